"""Fields of frozen dataclasses computed on first read: work a caller may never ask for (a
Cramer-Rao bound, names of null-space directions) is not done up front."""

from __future__ import annotations

from dataclasses import fields


class Deferred:
    """A field of a frozen dataclass that may be given as a function of no arguments instead of
    its value: the function is called on the first read and its value kept. The class using it
    defines ``__getstate__ = resolved_state`` so that it pickles (functions often do not)."""

    def __set_name__(self, owner, name: str) -> None:
        self._name = name

    def __get__(self, obj, owner=None):
        if obj is None:  # the class: no default value
            raise AttributeError(self._name)
        value = obj.__dict__[self._name]
        if callable(value):
            value = value()
            obj.__dict__[self._name] = value
        return value

    def __set__(self, obj, value) -> None:
        obj.__dict__[self._name] = value


def resolved_state(obj) -> dict:
    """The pickled state of a dataclass ``obj``: its fields, deferred ones computed."""
    return {**obj.__dict__, **{f.name: getattr(obj, f.name) for f in fields(obj)}}
