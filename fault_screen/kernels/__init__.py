"""Physics kernels: small pure numba functions of (coordinates, parameters, state) that return
local arrays. They know nothing of scenes, DOF numbering or solvers."""
