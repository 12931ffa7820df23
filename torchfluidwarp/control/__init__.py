"""Fit forces to goals: the one L-BFGS driver, keyframe control, image registration and pre-alignment.

* :mod:`~torchfluidwarp.control.optim`: :func:`minimize`, the one optimiser loop (closure, tolerance, NaN
  policy, progress, history) that every fit runs through;
* :mod:`~torchfluidwarp.control.newton`: the quasi-Newton start of a points-only keyframe fit (damped
  Gauss-Newton on a model Jacobian, roll-outs without autograd);
* :mod:`~torchfluidwarp.control.keyframes`: :func:`fit_keyframes`, marked points to their targets, with
  adjoint gradients;
* :mod:`~torchfluidwarp.control.images`: :func:`fit_images`, one image onto another by its pixels, with the
  image terms of :mod:`~torchfluidwarp.control.losses` (MSE, NCC, kornia's SSIM);
* :mod:`~torchfluidwarp.control.alignment`: the similarity/affine pre-alignment of two point sets (least squares,
  or robust to a few pairs far off).
"""

from torchfluidwarp.control.alignment import (
    apply_alignment,
    best_shift,
    estimate_alignment,
    interpolate_alignment,
    robust_alignment,
)
from torchfluidwarp.control.images import FoldWarning, ImageFit, LevelFit, fit_images
from torchfluidwarp.control.keyframes import (
    KeyframeFit,
    check_points,
    fit_keyframes,
    keyframe_loss,
    velocity_gradient_energy,
)
from torchfluidwarp.control.losses import image_loss, lncc_loss, mse_loss, ncc_loss, ssim_loss
from torchfluidwarp.control.optim import OptimResult, minimize

__all__ = [
    "apply_alignment",
    "best_shift",
    "estimate_alignment",
    "interpolate_alignment",
    "robust_alignment",
    "FoldWarning",
    "ImageFit",
    "LevelFit",
    "fit_images",
    "image_loss",
    "mse_loss",
    "ncc_loss",
    "ssim_loss",
    "lncc_loss",
    "KeyframeFit",
    "check_points",
    "fit_keyframes",
    "keyframe_loss",
    "velocity_gradient_energy",
    "OptimResult",
    "minimize",
]
