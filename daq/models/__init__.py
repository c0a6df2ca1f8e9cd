"""Models against measurements: model files, fit by multiple shooting, compare, diagnose (screening, candidates)."""
