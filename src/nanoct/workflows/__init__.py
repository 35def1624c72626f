"""Workflows above the solvers and the motion estimators: the whole-stack reconstruction."""
