"""Post-processing: smoothing, decimation, components, capping (Mesh in, Mesh out)."""
