"""sgdr: Spring-Mass 3D Gaussians on Mitsuba/Dr.Jit.

Reconstructs an elastic object from multi-view videos as a simulatable asset (Zhong et al.,
"Reconstruction and Simulation of Elastic Objects with Spring-Mass 3D Gaussians", ECCV 2024).
Importing sgdr has no side effects: the entry point picks the backend with
`sgdr.backend.init(...)`.
"""

__version__ = "0.1.0"
