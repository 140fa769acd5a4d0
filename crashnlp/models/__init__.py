"""The crash models: force laws, the parameter vector, the model forms and the forward
simulation."""
