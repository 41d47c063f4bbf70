"""Olfati-Saber 2006: flocking with alpha-, beta- and gamma-agents (Algorithms 1-3)."""
