"""Morphing two images: straight landmark paths, the forward warp of A, the inverse warp of B, the dissolve.

:func:`morph` returns a :class:`MorphResult`; :mod:`~torchfluidwarp.morph.morphing` holds the steps.
"""

from torchfluidwarp.morph.morphing import MorphResult, morph, region_of_interest, resize_pair

__all__ = ["MorphResult", "morph", "region_of_interest", "resize_pair"]
