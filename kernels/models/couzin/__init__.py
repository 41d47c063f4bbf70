"""Couzin et al. 2002: zones of repulsion, orientation and attraction (docs/models/couzin.md)."""
