"""Readers and writers, one module per file format. Only `io` and `data` touch files."""
