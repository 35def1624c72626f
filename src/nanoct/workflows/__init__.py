"""Workflows above the solvers and the motion estimators: the whole-stack reconstruction, and the export of a
reconstruction as image or shifts files."""
