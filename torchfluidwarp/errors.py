"""The library's exceptions, and whose fault each one is.

* :class:`InputError` (a ``ValueError``) and :class:`InputTypeError` (a ``TypeError``): the caller passed
  something the library cannot use; the message names the argument and the value received, and
  :attr:`~InputError.argument` holds the argument's name. The command line prints its one line and exits 2.
* :class:`FlowBlewUp` (an ``ArithmeticError``): the forces, the velocity or ``dt`` make the flow blow up or need
  too many sub-steps; the message says what to change. The command line prints it and exits 3.
* Anything else is a bug in the library: the command line prints the traceback and exits 1.

The library's warnings about a result (a morph that folds, marks let go, marks met loosely) are
:class:`AdvisedWarning` s (``RuntimeWarning``): their advice is a :class:`Hint` too, which the command line
words as its flags.

An error may carry a :class:`Hint`: what to change, naming the setting that changes it. The hint is kept apart
from the message so that a caller with its own names for the settings (the command line's flags) can say it in
its own terms with :meth:`InputError.explain`, instead of rewriting the message's text.

Example:
    >>> err = InputError(
    ...     "morph needs 9.0 GiB, above the limit of 8.0 GiB",
    ...     hint=Hint("ask for less, or raise the limit with {setting}", "max_memory", otherwise="ask for less"),
    ... )
    >>> str(err)
    'morph needs 9.0 GiB, above the limit of 8.0 GiB; ask for less, or raise the limit with max_memory'
    >>> err.explain({"max_memory": "--max-memory GIB"})
    'morph needs 9.0 GiB, above the limit of 8.0 GiB; ask for less, or raise the limit with --max-memory GIB'
    >>> err.explain({})
    'morph needs 9.0 GiB, above the limit of 8.0 GiB; ask for less'
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["Hint", "InputError", "InputTypeError", "FlowBlewUp", "AdvisedWarning"]


@dataclass(frozen=True)
class Hint:
    """What to change to get past an error, naming the setting that does it.

    Attributes:
        text: the advice, with ``{setting}`` where the setting's name goes
            (``"ask for less, or raise the limit with {setting}"``).
        setting: the setting's name as the library's signatures spell it (``"max_memory"``); a caller that names
            its settings otherwise (the command line) looks it up in its own table.
        spelling: how a Python caller sets it, e.g. ``"MapConfig(max_memory=...)"`` (default: ``setting``).
        otherwise: the advice for a caller that has no such setting (default: none at all).
    """

    text: str
    setting: str
    spelling: str | None = None
    otherwise: str = ""

    def render(self, name: str | None) -> str:
        """The advice with the setting called ``name``; :attr:`otherwise` when ``name`` is ``None``."""
        return self.otherwise if name is None else self.text.format(setting=name)


class _Explained(Exception):
    """What :class:`InputError`, :class:`InputTypeError` and :class:`FlowBlewUp` share: a message (the first line
    of which says what went wrong), the argument at fault and a :class:`Hint`."""

    def __init__(self, message: str, *, argument: str | None = None, hint: Hint | None = None) -> None:
        self.message = message
        self.argument = argument
        self.hint = hint
        super().__init__(message if hint is None else self._with(hint.render(hint.spelling or hint.setting)))

    def _with(self, advice: str) -> str:
        return f"{self.message}; {advice}" if advice else self.message

    def explain(self, names: Mapping[str, str]) -> str:
        """The message with its hint in a caller's terms.

        Args:
            names: the caller's name for each setting it has, by the library's name (``{"max_memory":
                "--max-memory GIB"}``). A hint whose setting is not in ``names`` gives its ``otherwise`` advice.

        Returns:
            the message, and the hint after a ``"; "`` when there is advice to give.
        """
        if self.hint is None:
            return self.message
        return self._with(self.hint.render(names.get(self.hint.setting)))


class InputError(_Explained, ValueError):
    """A value the caller passed cannot be used.

    Args:
        message: what is wrong, naming the argument and the value received (``"max_iter must be >= 1, got 0"``).
        argument: the argument's name as the function's signature spells it (``"max_iter"``), or ``None`` when no
            single argument is at fault. The command line names its own flag for it.
        hint: what to change, when the message alone does not say it.

    Attributes:
        message, argument, hint: as given; ``str(error)`` is the message and the hint in Python's terms.
    """


class InputTypeError(_Explained, TypeError):
    """An argument of a type the library cannot use (``"dtype must be a torch.dtype, got str 'float32'"``).

    The ``TypeError`` twin of :class:`InputError`, with the same arguments and attributes. A ``TypeError`` that is
    not an ``InputTypeError`` did not come from a check of the caller's input: the command line reports it as a
    bug.
    """


class FlowBlewUp(_Explained, ArithmeticError):
    """A flow that cannot be run or carried: its velocity became non-finite, or it needs more than
    ``max_substeps`` sub-steps in one step.

    Args:
        message: what happened (the step, the strain, ``dt``); its first line stands alone.
        argument: the argument whose value made it blow up, when one is (``"dt"``); usually ``None``.
        hint: what to change, e.g. ``Hint("reduce the forces or dt, or raise the limit with {setting}",
            "max_substeps", otherwise="reduce the forces or dt")``.

    The fits catch this one alone: a trial step that makes the flow blow up is a step too long, not a bug
    (:func:`~torchfluidwarp.control.optim.minimize`'s ``undefined``).
    """


class AdvisedWarning(_Explained, RuntimeWarning):
    """A warning about a result, with a :class:`Hint` (what to change, or where to look) that a caller says in its
    own terms (:meth:`~InputError.explain`): the command line prints ``--straightness X`` where Python code
    reads ``NaturalSettings.straightness``.

    Example:
        >>> w = AdvisedWarning("the maps fold", hint=Hint("raise {setting}", "straightness",
        ...                    spelling="NaturalSettings.straightness"))
        >>> str(w), w.explain({"straightness": "--straightness X"})
        ('the maps fold; raise NaturalSettings.straightness', 'the maps fold; raise --straightness X')
    """
