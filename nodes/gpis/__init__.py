"""GPIS node: Gaussian process implicit surface from tactile contacts (paper 002, Sec. 2.3 and 3.2).

Pure modules: ``kernels`` (thin-plate and Gaussian covariances with derivative blocks), ``core``
(``GPISConfig`` and the incrementally factorised ``GPIS``), ``surface`` (marching-cubes meshes of
f = 0 with GP normals and variance) and ``bench`` (timing of one update plus the local surface).
"""
