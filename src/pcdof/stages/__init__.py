"""The pipeline's stages, one package each: registration, hole filling, circle of confusion, highlights, render."""
