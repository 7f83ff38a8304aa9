"""P1 finite elements, independent of particles and windows.

=============== ===============================================================================
``operators``   mass, stiffness, lumped mass, element gradients, assembled with scikit-fem and
                folded onto periodic dofs; the exact P1 shape-tensor integrals
``periodic``    periodic identification of dofs by geometry
``solvers``     linear solvers built once and reused (LU, pyamg + Krylov, exact tensor product)
``blocks``      every window's principal submatrix in one block-diagonal matrix, and CG on it
``kernels``     the compiled passes that build that matrix's pattern (numba, imported on first use)
``meshfiles``   triangle meshes from and to files (meshio)
=============== ===============================================================================
"""
