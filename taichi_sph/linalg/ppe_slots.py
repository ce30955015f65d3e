"""The numbering shared by the PPE's kernels: a particle's role in the system, the slots of the scalar field the
reductions go into, and the slots of the f64 solve state on the device (`MatrixFreePPE.progress`)."""

# role of a particle in the system
UNKNOWN, DIRICHLET, NOT_IN_PPE = 0, 1, 2
# slots of the scalar field the kernels reduce into
# (N_MEAN: the rows in the pure-Neumann means, the unknowns but extrapolation rows, `MatrixFreePPE` flow_rows)
RR, BB, RZ, RZ_NEW, PQ, N_UNKNOWN, N_DIRICHLET, SUM_B, SUM_P, SUM_Z, SUM_R, N_MEAN = range(12)
# slots of the f64 solve state (`MatrixFreePPE.progress`): the device-side stopping test's inputs and outputs
DONE, ITERATIONS, RESIDUAL, NORM_B, PINNED, TRIVIAL, TOLERANCE, MAX_ITERATIONS, STARTING = range(9)
