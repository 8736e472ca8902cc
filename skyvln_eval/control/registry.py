"""Controllers by name, with settings from a mapping or a YAML file.

Names: ``pid`` (cascaded PID), ``mpc`` (linear MPC; alias ``lmpc``) and ``nmpc`` (the
paper's NMPC) - the rows of the paper's control ablation. Settings are the fields of the
controller's config dataclass (:class:`~skyvln_eval.control.pid.PidConfig`,
:class:`~skyvln_eval.control.mpc_config.MpcConfig`), nested dataclasses as nested
mappings; an unknown name or field is a :class:`ConfigError` that names it and suggests
close matches. The NMPC and linear MPC modules (CasADi solvers) are imported on use.

A controller YAML file (``configs/controllers/*.yaml``) reads::

    controller: nmpc
    settings:
      horizon_steps: 20
      weights: {state: [10, 10, 10, 1, 1, 1, 0.5, 0.5]}
"""

from __future__ import annotations

import dataclasses
import difflib
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from skyvln_eval.control.base import Controller
from skyvln_eval.control.mpc_config import MpcConfig
from skyvln_eval.control.pid import PidConfig
from skyvln_eval.errors import ConfigError, SettingsError, UnknownNameError
from skyvln_eval.fileio import load_yaml

T = TypeVar("T")


def _nmpc(config: MpcConfig) -> Controller:
    from skyvln_eval.control.mpc import NmpcController

    return NmpcController(config)


def _mpc(config: MpcConfig) -> Controller:
    from skyvln_eval.control.mpc import LinearMpcController

    return LinearMpcController(config)


def _pid(config: PidConfig) -> Controller:
    from skyvln_eval.control.pid import PidController

    return PidController(config)


#: name -> (config class, factory, whether it plans around the obstacle forecast with a
#: keep-out constraint it may relax with slack: the PID only tracks the reference, so
#: "steps with the obstacle constraint relaxed" has no value for it, not 0)
_REGISTRY: dict[str, tuple[type[Any], Callable[[Any], Controller], bool]] = {
    "pid": (PidConfig, _pid, False),
    "mpc": (MpcConfig, _mpc, True),
    "nmpc": (MpcConfig, _nmpc, True),
}
_ALIASES = {"lmpc": "mpc", "linear_mpc": "mpc"}


def controller_names() -> list[str]:
    """The registered controller names (aliases not included)."""
    return sorted(_REGISTRY)


def make_controller(name: str, settings: Mapping[str, Any] | None = None) -> Controller:
    """A new controller ``name`` with ``settings`` overriding its config's defaults."""
    config = controller_config(name, settings)
    return _REGISTRY[_ALIASES.get(name, name)][1](config)


def has_obstacle_constraint(name: str) -> bool | None:
    """Whether controller ``name`` keeps out of obstacles by a constraint of its plan
    (``None``: not a registered controller, e.g. one a user logged under another name)."""
    entry = _REGISTRY.get(_ALIASES.get(name, name))
    return None if entry is None else entry[2]


def controller_config(name: str, settings: Mapping[str, Any] | None = None) -> Any:
    """The settings of controller ``name`` (its config dataclass, ``settings`` over the
    defaults), checked without building the controller: no solver is made or compiled.

    An unknown name is an :class:`UnknownNameError`, a bad field a :class:`SettingsError`.
    """
    key = _ALIASES.get(name, name)
    if key not in _REGISTRY:
        raise UnknownNameError("controller", name, [*_REGISTRY, *_ALIASES])
    return config_from_mapping(_REGISTRY[key][0], settings or {}, f"{key} settings")


def load_controller(path: str | Path) -> Controller:
    """The controller a YAML file describes (``controller: name``, optional ``settings:``)."""
    path = Path(path)
    try:
        document = load_yaml(path.read_text(encoding="utf-8"), path)
    except (OSError, yaml.YAMLError) as error:
        raise ConfigError(f"{path}: cannot read the controller config: {error}") from error
    if not isinstance(document, dict) or "controller" not in document:
        raise ConfigError(f"{path}: expected a mapping with a 'controller' field")
    unknown = set(document) - {"controller", "settings"}
    if unknown:
        raise ConfigError(f"{path}: unknown field(s) {', '.join(sorted(unknown))}")
    try:
        return make_controller(str(document["controller"]), document.get("settings") or {})
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from error


def config_from_mapping(cls: type[T], values: Mapping[str, Any], where: str = "settings") -> T:
    """An instance of dataclass ``cls`` from ``values``, nested dataclasses included.

    Lists become tuples; unknown fields and wrong types raise :class:`SettingsError` naming
    the field path (e.g. ``nmpc settings.weights.state``).
    """
    return _from_mapping(cls, values, where, ())


def _from_mapping(cls: type[T], values: Any, where: str, path: tuple[str, ...]) -> T:
    here = ".".join((where, *path))
    if not isinstance(values, Mapping):
        problem = f"must be a mapping, got {type(values).__name__}"
        raise SettingsError(f"{here} {problem}", ".".join(path), problem)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    hints = typing.get_type_hints(cls)
    kwargs: dict[str, Any] = {}
    for key, value in values.items():
        if key not in fields:
            close = difflib.get_close_matches(str(key), list(fields), n=3)
            hint = f" Did you mean {', '.join(repr(c) for c in close)}?" if close else ""
            known = f"did you mean {', '.join(repr(c) for c in close)}?" if close else ""
            problem = f"unknown field of the {where} ({known or 'known: ' + ', '.join(fields)})"
            raise SettingsError(
                f"{here}: unknown field {key!r}.{hint}", ".".join((*path, str(key))), problem
            )
        kwargs[key] = _convert(hints[key], value, where, (*path, key))
    try:
        return cls(**kwargs)
    except (TypeError, ConfigError) as error:
        # The dataclass's own checks (``MpcConfig.horizon_steps must be ...``).
        raise SettingsError(f"{here}: {error}", ".".join(path), str(error)) from error


def _convert(hint: Any, value: Any, where: str, path: tuple[str, ...]) -> Any:
    def fail(problem: str) -> SettingsError:
        return SettingsError(f"{'.'.join((where, *path))} {problem}", ".".join(path), problem)

    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return _from_mapping(hint, value, where, path)
    origin = typing.get_origin(hint)
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise fail(f"must be a list, got {value!r}")
        return tuple(
            _number(v, where, (*path[:-1], f"{path[-1]}[{i}]")) for i, v in enumerate(value)
        )
    if hint is float:
        return _number(value, where, path)
    if hint is int and (isinstance(value, bool) or not isinstance(value, int)):
        raise fail(f"must be an integer, got {value!r}")
    if hint is bool and not isinstance(value, bool):
        raise fail(f"must be true or false, got {value!r}")
    if origin is typing.Literal and value not in typing.get_args(hint):
        allowed = ", ".join(repr(a) for a in typing.get_args(hint))
        raise fail(f"must be one of {allowed}, got {value!r}")
    return value


def _number(value: Any, where: str, path: tuple[str, ...]) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        problem = f"must be a number, got {value!r}"
        if isinstance(value, str) and _looks_like_yaml_exponent(value):
            # YAML 1.1 reads 1.0e12 as text: its exponent needs a sign (1.0e+12).
            mantissa, _, exponent = value.lower().partition("e")
            problem += f" (text: YAML wants a signed exponent, {mantissa}e+{exponent})"
        raise SettingsError(f"{'.'.join((where, *path))} {problem}", ".".join(path), problem)
    return float(value)


def _looks_like_yaml_exponent(text: str) -> bool:
    """Whether ``text`` is a number in exponent form without the exponent's sign, which
    YAML 1.1 (PyYAML) reads as a string."""
    mantissa, e, exponent = text.lower().partition("e")
    try:
        float(mantissa)
    except ValueError:
        return False
    return bool(e) and exponent.isdigit()
