"""The face model: the base mesh, its regions, and the deformations the parameters drive."""
