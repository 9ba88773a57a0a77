"""Figures, animations and reports: the only package that imports matplotlib."""
