"""The whole study from one call: stages, plan, report."""
