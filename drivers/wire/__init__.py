"""Wire formats of serial IMUs, parsed in bulk."""
