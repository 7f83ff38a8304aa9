"""The model of Hadjifrangiskou, Valani & Pinto, independent of any discretisation.

``parameters``  the parameters and pointwise functions of φ (:class:`~femphase.model.parameters.ModelParameters`)
``energy``      the free energy as a list of terms, its variational derivative and bounds
``minimal``     the paper's minimal one-variable ODE model of the shape oscillations
"""
