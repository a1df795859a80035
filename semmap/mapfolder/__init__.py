"""The map folder: writing and reading what semmap build produces."""
