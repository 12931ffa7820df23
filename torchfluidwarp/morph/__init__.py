"""Morphing two images: straight landmark paths, the forward warp of A, the inverse warp of B, the dissolve.

:func:`morph` (:mod:`~torchfluidwarp.morph.morphing`) takes typed settings (:mod:`~torchfluidwarp.morph.settings`:
:class:`NaturalSettings` or :class:`PaperSettings`, :class:`Timing`, :class:`Blending`, :class:`Matching`), fits
the flow (:mod:`~torchfluidwarp.morph.fit`) and returns a :class:`MorphResult` (:mod:`~torchfluidwarp.morph.result`)
that renders frames on demand (:mod:`~torchfluidwarp.morph.render`): one at any time ``t``, all ``N`` streamed, or
all at once.

The package is also the function: ``torchfluidwarp.morph(a, b, ...)`` and ``from torchfluidwarp import morph;
morph(a, b, ...)`` call :func:`morph`, while ``import torchfluidwarp.morph as m; m.NaturalSettings`` and
``import torchfluidwarp.morph.fit`` reach the package (one name, which a function at the top level would have
hidden).
"""

import importlib
import inspect
import sys
import types
from typing import Any

from torchfluidwarp.morph.morphing import morph, region_of_interest, resize_pair
from torchfluidwarp.morph.regions import hull_mask, paste_back
from torchfluidwarp.morph.render import MorphFrames
from torchfluidwarp.morph.result import MorphResult
from torchfluidwarp.morph.sequence import AverageResult, MorphSequence, average, morph_sequence
from torchfluidwarp.morph.settings import Blending, Matching, MorphSettings, NaturalSettings, PaperSettings, Timing

__all__ = ["MorphFrames", "MorphResult", "morph", "region_of_interest", "resize_pair", "hull_mask", "paste_back"]
__all__ += ["MorphSequence", "morph_sequence", "AverageResult", "average"]
__all__ += ["NaturalSettings", "PaperSettings", "MorphSettings", "Timing", "Blending", "Matching"]


class _Callable(types.ModuleType):
    """This package's module type: calling the package calls :func:`morph`."""

    def __call__(self, *args: Any, **kwargs: Any) -> MorphResult:
        return morph(*args, **kwargs)

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        # pickled by name, as a function is (a process pool sends ``morph`` to its workers)
        return importlib.import_module, (self.__name__,)


__signature__ = inspect.signature(morph)  # what help() and IDEs show for a call of the package
sys.modules[__name__].__class__ = _Callable
