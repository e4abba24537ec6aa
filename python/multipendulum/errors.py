"""Exceptions. Bad input raises :class:`InputError` (a ``ValueError``) naming the field, the index,
the value and what was expected; a run that cannot continue raises :class:`IntegrationError`
(a ``RuntimeError``) whose ``t`` attribute is the time it failed."""
from ._core import InputError, IntegrationError

__all__ = ["InputError", "IntegrationError"]
