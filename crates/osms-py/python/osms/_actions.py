"""A policy's answer read as real numbers, shared by ``osms.eval`` (a batch) and ``CatchEnv``
(one rollout), which each check the shape they expect."""

import numpy as np


def real_array(raw, refuse, *, many):
    """``raw`` as a numpy array of integers or floats, or ``refuse(problem)`` raised: for
    ``None`` (a forgotten ``return``), what numpy cannot make an array of, and anything not real
    (complex, text, objects). ``many`` words the problem for a batch of actions."""
    verb, noun = ("are", "actions") if many else ("is", "action")
    if raw is None:
        raise refuse(f"{verb} None (does the policy return its {noun}?)")
    try:
        with np.errstate(all="ignore"):
            a = np.asarray(raw)
    except (TypeError, ValueError) as e:
        raise refuse(f"{verb} not an array ({e})") from None
    if a.dtype.kind not in "iuf":
        raise refuse(f"{verb} not real numbers (dtype {a.dtype})")
    return a
