"""Declared, described and validated node parameters.

Each parameter is a :class:`Param`: a default, a description, an optional
inclusive range (published as ``FloatingPointRange`` / ``IntegerRange`` so
``ros2 param describe`` shows it), optional string choices, and
``read_only`` for what only takes effect at start-up.

A reconstruction setting shared with ``sfs-reconstruct``
(:class:`sfs_ros.core.settings.Setting`) becomes a parameter by :meth:`Param.of`: its
meaning, range, choices and the cell's default come from there.

* :func:`declare` declares them on a node and returns their values,
  raising :class:`ParameterError` (one line naming the parameter) for a value
  out of range, of the wrong type or not among the choices; ``main()``
  prints it and exits non-zero.
* :func:`validating_callback` builds the set-parameters callback that
  checks runtime changes the same way, plus the node's own cross-field
  validation, and refuses them with a reason before anything is applied.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node

from sfs_ros.core.settings import Setting

__all__ = ["Param", "ParameterError", "declare", "read", "check", "validating_callback"]


class ParameterError(ValueError):
    """An invalid parameter value; ``str()`` is one line that names the parameter."""

    def __init__(self, name: str, message: str):
        super().__init__(f"invalid parameter '{name}': {message}")
        self.name = name
        self.reason = message


@dataclass(frozen=True)
class Param:
    """A node parameter.

    name : str
    default : bool, int, float, str, or a non-empty list of int / float / str
        (its type is the parameter's type).
    description : str
    bounds : (low, high), optional
        Inclusive range of a number, or of every element of a list of numbers.
    choices : tuple of str, optional
        Allowed values of a string.
    read_only : bool
        Settable at start-up only (``--params-file``, ``-p``).
    constraints : str
        Further rules in words (``additional_constraints``), e.g. what 0 means.
    """

    name: str
    default: Any
    description: str
    bounds: tuple[float, float] | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = False
    constraints: str = ""

    @classmethod
    def of(cls, setting: Setting, *, read_only: bool = False, constraints: str = "") -> Param:
        """The parameter of a reconstruction setting: its name, the cell's default
        (``cell_default``), its description, bounds and choices (read now)."""
        bounds = setting.bounds
        if bounds is not None and bounds[1] is None:
            raise ValueError(f"setting {setting.name} has no upper bound; a parameter needs one")
        return cls(setting.name, setting.cell_default, setting.description, bounds=bounds,
                   choices=None if setting.choices is None else tuple(setting.choices()),
                   read_only=read_only, constraints=constraints)

    def descriptor(self) -> ParameterDescriptor:
        """The ``rcl_interfaces/ParameterDescriptor`` of this parameter."""
        rules = [self.constraints] if self.constraints else []
        if self.choices is not None:
            rules.append(f"one of {list(self.choices)}")
        if self.bounds is not None and isinstance(self.default, list):
            rules.append(f"every element in [{self.bounds[0]}, {self.bounds[1]}]")
        descriptor = ParameterDescriptor(description=self.description, read_only=self.read_only,
                                         additional_constraints="; ".join(rules))
        if self.bounds is not None and not isinstance(self.default, list):
            low, high = self.bounds
            if isinstance(self.default, float):
                descriptor.floating_point_range = [
                    FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]
            else:
                descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high),
                                                         step=1)]
        return descriptor

    def expected(self) -> str:
        """What a valid value looks like, in words."""
        kind = type(self.default).__name__
        if isinstance(self.default, list):
            kind = f"list of {len(self.default)} {type(self.default[0]).__name__}"
        parts = [kind]
        if self.bounds is not None:
            parts.append(f"in [{self.bounds[0]}, {self.bounds[1]}]")
        if self.choices is not None:
            parts.append(f"one of {list(self.choices)}")
        if self.constraints:
            parts.append(f"({self.constraints})")
        return " ".join(parts)


def check(param: Param, value) -> str | None:
    """Why ``value`` is not valid for ``param`` (None if it is): type, bounds, choices."""
    default = param.default
    if isinstance(default, list):
        if not isinstance(value, (list, tuple)) and not hasattr(value, "tolist"):
            return f"got {value!r}, expected {param.expected()}"
        items = list(value.tolist() if hasattr(value, "tolist") else value)
        element = type(default[0])
        if not items or not all(isinstance(v, element) and not isinstance(v, bool)
                                for v in items):
            return f"got {value!r}, expected {param.expected()}"
    else:
        ok = isinstance(value, type(default)) and (isinstance(default, bool)
                                                   or not isinstance(value, bool))
        if not ok:
            return f"got {value!r} of type {type(value).__name__}, expected {param.expected()}"
        items = [value]
    if param.bounds is not None and not all(param.bounds[0] <= v <= param.bounds[1]
                                            for v in items):
        return f"got {value!r}, expected {param.expected()}"
    if param.choices is not None and value not in param.choices:
        return f"got {value!r}, expected {param.expected()}"
    return None


def declare(node: Node, params: Sequence[Param]) -> dict[str, Any]:
    """Declare ``params`` on ``node`` (overrides from ``--params-file`` / ``-p`` applied)
    and return ``{name: value}``; raises :class:`ParameterError` for an invalid value."""
    for param in params:
        try:
            node.declare_parameter(param.name, param.default, param.descriptor())
        except InvalidParameterValueException as exc:
            # rclpy's text: "Invalid parameter value (<value>) for parameter. Reason: ..."
            found = re.match(r"Invalid parameter value \((.*)\) for parameter", str(exc))
            got = f"got {found.group(1)}" if found else str(exc)
            raise ParameterError(param.name, f"{got}, expected {param.expected()}") from None
        except InvalidParameterTypeException as exc:
            # rclpy's text: "Trying to set parameter '<name>' to '<value>' of type '<TYPE>', ..."
            found = re.search(r"to '(.*)' of type '(\w+)'", str(exc))
            got = f"got {found.group(1)} of type {found.group(2).lower()}" if found else str(exc)
            raise ParameterError(param.name, f"{got}, expected {param.expected()}") from None
    values = read(node, params)
    for param in params:
        reason = check(param, values[param.name])
        if reason is not None:
            raise ParameterError(param.name, reason)
    return values


def read(node: Node, params: Sequence[Param]) -> dict[str, Any]:
    """Current ``{name: value}`` of declared ``params`` (lists as Python lists)."""
    values = {}
    for param in params:
        value = node.get_parameter(param.name).value
        values[param.name] = list(value) if isinstance(param.default, list) else value
    return values


def output_folder(value: str, purpose: str, subfolder: str = "") -> Path:
    """The folder the ``output_dir`` parameter (``value``) names, its ``subfolder`` (if
    any) created if needed; :class:`ParameterError` naming ``output_dir`` for an empty
    ``value`` ("is required: the folder for ``purpose``") or a folder that cannot be made."""
    if not value.strip():
        raise ParameterError("output_dir", f"is required: the folder for {purpose}")
    folder = Path(value) / subfolder if subfolder else Path(value)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ParameterError("output_dir", str(exc)) from None
    return folder


def validating_callback(node: Node, params: Sequence[Param],
                        validate: Callable[[dict[str, Any]], None]
                        ) -> Callable[[list], SetParametersResult]:
    """Set-parameters callback for ``node.add_on_set_parameters_callback``.

    Checks each changed parameter of ``params`` (type, bounds, choices), then
    calls ``validate`` with all of ``params``' values as they would be after
    the change; a ``ValueError`` from it refuses the change with its message.
    Parameters not in ``params`` are left to other callbacks.
    """
    by_name = {p.name: p for p in params}

    def callback(changes: list) -> SetParametersResult:
        values = read(node, params)
        for change in changes:
            param = by_name.get(change.name)
            if param is None:
                continue
            value = list(change.value) if isinstance(param.default, list) else change.value
            reason = check(param, value)
            if reason is not None:
                return SetParametersResult(successful=False,
                                           reason=str(ParameterError(param.name, reason)))
            values[param.name] = value
        try:
            validate(values)
        except ValueError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    return callback
