"""Seeing motion: a self-contained offline HTML viewer (`viewer`) of a `Scene` (`scene`), matplotlib figures
(`plots`), and headless Chromium to check and screenshot the viewer (`browser`)."""
