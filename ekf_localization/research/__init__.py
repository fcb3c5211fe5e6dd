"""Reproductions of the seed papers and their paper-only models, outside the runtime import graph.

Nothing outside ``research`` imports from here.
"""
