"""Dataset folders, importers and image measurement."""
