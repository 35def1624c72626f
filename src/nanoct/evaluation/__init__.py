"""Evaluation: metrics, the paper's tables and conclusions, figures."""
