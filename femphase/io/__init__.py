"""Files: what a run directory holds, written so that a kill loses nothing, and read back.

``files``        atomic writes, JSON, the CSV tables, fault injection points
``checkpoints``  HDF5 checkpoints of a state
``fields``       field frames (XDMF + HDF5, for ParaView)
``rundir``       a run directory's outputs, status (run.json), log and resume rules
``provenance``   what ran where: versions, git commit, host, threads
``reader``       :func:`~femphase.io.reader.open_run`, the one reader of a run directory
``console``      the femphase logger on stderr, and warnings through it (one line each)
"""
