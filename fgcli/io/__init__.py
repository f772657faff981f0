"""EXR I/O: low-level channel access (exr), sequences, layouts, cameras, writers."""
