"""Matching with incomplete data: markerless fits, bodies from markers alone."""
