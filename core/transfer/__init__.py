"""What correspondence buys (Allen et al. 2003, sections 4.1 and 4.6): morphing, skeleton and
skin transfer, colour transfer -- all defined once on the template, carried to every body."""

from core.transfer.morph import MAX_BODIES, morph, morph_colors, morph_glb, morph_targets

__all__ = ["MAX_BODIES", "morph", "morph_colors", "morph_glb", "morph_targets"]
