"""The paper's mu-law tone curve T(G) = log(1 + mu G) / log(1 + mu), for NumPy arrays and torch
tensors alike: the tone map of the output video, the metrics' and the training loss's domain, and
the domain RMB-Net predicts in. A bottom-layer module (no torch import), so every layer shares one
definition.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def mu_law(x: Any, mu: float = 5000.0) -> Any:
    """The paper's mu-law curve ``log(1 + mu*x) / log(1 + mu)`` for NumPy arrays or torch tensors.

    Negative values are clipped to 0 and huge values are clipped before the multiply so the result
    is always finite (NaN inputs stay NaN). Torch tensors stay tensors, so it can serve as a loss.
    """
    if mu <= 0:
        raise ValueError(f"mu must be positive, got {mu}")
    denominator = math.log1p(mu)
    if hasattr(x, "clamp") and not isinstance(x, np.ndarray):  # a torch tensor, kept differentiable
        upper = _float_max(str(x.dtype)) / (2.0 * mu)
        return (x.clamp(min=0.0, max=upper) * mu).log1p() / denominator
    array = np.asarray(x)
    if not np.issubdtype(array.dtype, np.floating):
        array = array.astype(np.float64)
    upper = np.finfo(array.dtype).max / (2.0 * mu)  # headroom so the multiply cannot overflow
    return (np.log1p(np.clip(array, 0.0, upper) * array.dtype.type(mu)) / denominator).astype(
        array.dtype, copy=False
    )


def _float_max(torch_dtype_name: str) -> float:
    """Largest finite value of a torch float dtype, by name (avoids importing torch here)."""
    name = torch_dtype_name.rsplit(".", 1)[-1]
    return {"float16": 65504.0, "bfloat16": 3.3895e38, "float32": 3.4028e38}.get(name, 1.7976e308)


def inverse_mu_law(t: Any, mu: float = 5000.0) -> Any:
    """Inverse of ``mu_law`` on [0, 1]: (exp(t log(1 + mu)) - 1) / mu (tensor or array)."""
    if hasattr(t, "expm1") and not isinstance(t, np.ndarray):
        return (t * math.log1p(mu)).expm1() / mu
    return np.expm1(np.asarray(t) * math.log1p(mu)) / mu
