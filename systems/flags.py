"""The project's 0/1 flags (an estimate's valid flag, a detection's seen flag, the landing window's open flag, ...),
carried as float entries of a vector port or a log: 1.0 set, 0.0 not set.

Read them through `is_set`: a flag is set only above 0.5, so a NaN flag (a broken filter, a damaged log) reads as
not set. `bool(nan)` is True and `nan < 0.5` is False, which is why `bool(flag)` and `not flag < 0.5` must not be
used."""


def is_set(flag):
    """True where `flag` (a float, or elementwise a NumPy array of them) is above 0.5; NaN reads as False."""
    return flag > 0.5
