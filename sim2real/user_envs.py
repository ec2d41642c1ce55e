"""Your own envs behind ``model:``/``env:`` ids: an MJCF file or a factory, built into an env.

The building half of :mod:`sim2real.sources` (which resolves and checks ``--task``/``--model``/``--env``):
:func:`sim2real.make` calls :func:`make_user_env` for ids starting with ``model:`` or ``env:``, so this module imports
nothing of the task registry (``sim2real.tasks`` imports it, not the other way round).

Example:
    >>> import_factory("collections:OrderedDict", "--env").__name__
    'OrderedDict'
    >>> as_gym({"not": "an env"}, "pkg.mod:make", "--env", {})
    Traceback (most recent call last):
    ...
    sim2real.user_envs.SourceError: `--env` 'pkg.mod:make' returns a dict, not a gymnasium.Env, a dm_env.Environment or a TorchRL EnvBase.
"""

from __future__ import annotations

import contextlib
import difflib
import importlib
import os
import sys
from collections.abc import Callable, Mapping
from typing import Any

import gymnasium as gym

__all__ = [
    "ENV_PREFIX",
    "MODEL_PREFIX",
    "SourceError",
    "as_gym",
    "build_factory",
    "build_model",
    "close_quietly",
    "import_factory",
    "is_env",
    "make_user_env",
    "module_file",
]

#: Prefix of the id of an MJCF-file source.
MODEL_PREFIX = "model:"
#: Prefix of the id of an env-factory source.
ENV_PREFIX = "env:"
_OPTIONS = ("render_mode", "width", "height", "max_episode_steps", "control_timestep", "reset_noise")


class SourceError(ValueError):
    """A ``--task``/``--model``/``--env`` (or YAML ``task:``/``model:``/``env:``) that does not give an env."""


def close_quietly(obj: Any) -> None:
    """Closes ``obj`` if it can be closed, ignoring what a half-built user env raises."""
    close = getattr(obj, "close", None)
    if callable(close):
        with contextlib.suppress(Exception):  # closing a half-built user env must not hide the real error
            close()


def is_env(obj: Any) -> bool:
    """A gymnasium env, a ``dm_env.Environment`` or a TorchRL ``EnvBase``."""
    if isinstance(obj, gym.Env):
        return True
    import dm_env

    if isinstance(obj, dm_env.Environment):
        return True
    try:
        from torchrl.envs import EnvBase
    except ImportError:  # pragma: no cover - torchrl is a dependency
        return False
    return isinstance(obj, EnvBase)


def import_factory(spec: str, argument: str, base: str | os.PathLike[str] | None = None) -> Callable[[], Any]:
    """The callable named by ``'package.module:factory'``. When the module is not found, the working folder and then
    ``base`` (the folder of the spec that names it) are tried: the console script puts neither on ``sys.path``, and a
    user's own module usually lives in one of them. A folder that finds it stays on ``sys.path`` (so later builds
    and spawned workers import it too)."""
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr or ":" in attr:
        raise SourceError(f"`{argument}` must look like 'package.module:factory'. Received {spec!r}.")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as first:
        if first.name != module_name.split(".")[0]:
            raise SourceError(f"`{argument}` {spec!r}: cannot import module {module_name!r}: {first}.") from first
        try:
            module = _import_beside(module_name, [os.getcwd(), *([os.fspath(base)] if base is not None else [])])
        except ImportError as err:
            raise SourceError(f"`{argument}` {spec!r}: cannot import module {module_name!r}: {err}.") from err
        except Exception as err:  # found, but it fails while importing
            raise SourceError(
                f"`{argument}` {spec!r}: importing module {module_name!r} raised {type(err).__name__}: {err}"
            ) from err
        if module is None:
            raise SourceError(f"`{argument}` {spec!r}: cannot import module {module_name!r}: {first}.") from first
    except Exception as err:  # a module that fails while importing (syntax error, its own ImportError)
        raise SourceError(
            f"`{argument}` {spec!r}: importing module {module_name!r} raised {type(err).__name__}: {err}"
        ) from err
    factory = getattr(module, attr, None)
    if factory is None:
        names = [n for n in dir(module) if not n.startswith("_")]
        close = difflib.get_close_matches(attr, names, n=3, cutoff=0.6)
        hint = f" Close matches: {', '.join(repr(c) for c in close)}." if close else ""
        raise SourceError(f"`{argument}` {spec!r}: module {module_name!r} has no attribute {attr!r}.{hint}")
    if not callable(factory):
        raise SourceError(
            f"`{argument}` {spec!r} must name a callable that returns an env. Received {type(factory).__name__}."
        )
    return factory


def module_file(spec: str) -> str | None:
    """The file of the module an ``--env`` factory ``'package.module:factory'`` lives in, or None when it does not
    import (that is reported where the source is resolved) or has no file: an input of the command, which no output
    may overwrite (``train --env my_robot:make --out my_robot.py`` replaced the user's module with a checkpoint)."""
    try:
        import_factory(spec, "--env")
    except SourceError:
        return None
    path = getattr(sys.modules.get(spec.partition(":")[0]), "__file__", None)
    return path if isinstance(path, str) else None


def _import_beside(module_name: str, folders: list[str]) -> Any:
    """``module_name`` imported from the first of ``folders`` (not yet on ``sys.path``) that holds it, that folder
    left on ``sys.path``; None when none does. Errors raised while importing it propagate."""
    top = module_name.split(".")[0]
    for folder in dict.fromkeys(os.path.abspath(f) for f in folders):
        if folder in sys.path:
            continue
        sys.path.insert(0, folder)
        try:
            return importlib.import_module(module_name)
        except ModuleNotFoundError as err:
            sys.path.remove(folder)
            if err.name != top:  # the module is there but imports something missing: say so
                raise
        except BaseException:
            sys.path.remove(folder)
            raise
    return None


def build_model(path: str, argument: str, options: Mapping[str, Any]) -> gym.Env:
    """An :class:`~sim2real.mjcf_env.MjcfEnv` of the MJCF file ``path``."""
    from sim2real.mjcf_env import MjcfEnv

    unknown = sorted(set(options) - set(_OPTIONS))
    if unknown:
        raise SourceError(f"options of `{argument}` must be among {list(_OPTIONS)}. Received {unknown}.")
    try:
        return MjcfEnv(path, **options)
    except FileNotFoundError as err:
        raise SourceError(f"`{argument}` {path!r} does not exist.") from err
    except ValueError as err:
        raise SourceError(f"`{argument}`: {err}") from err


def build_factory(spec: str, argument: str) -> Any:
    """What the factory ``spec`` returns, checked to be an env (gymnasium, dm_env or TorchRL)."""
    factory = import_factory(spec, argument)
    try:
        obj = factory()
    except Exception as err:  # a user's factory may raise anything; say whose it was
        raise SourceError(f"`{argument}` {spec!r}: the factory raised {type(err).__name__}: {err}") from err
    if not is_env(obj):
        close_quietly(obj)
        raise SourceError(
            f"`{argument}` {spec!r} must return a gymnasium.Env, a dm_env.Environment or a TorchRL "
            f"EnvBase. Received {type(obj).__module__}.{type(obj).__qualname__}."
        )
    return obj


def as_gym(obj: Any, spec: str, argument: str, options: Mapping[str, Any]) -> gym.Env:
    """A factory's env as a gymnasium env (a dm_env through :class:`sim2real.DmEnvToGym` with ``options``).

    Raises:
        SourceError: options for a gymnasium env, a TorchRL env (no gymnasium view) or not an env at all.
    """
    if isinstance(obj, gym.Env):
        if options:
            close_quietly(obj)
            raise SourceError(
                f"`{argument}` {spec!r} returns a gymnasium env, which takes no options. Received {sorted(options)}."
            )
        return obj
    import dm_env

    if isinstance(obj, dm_env.Environment):
        from sim2real.adapters import DmEnvToGym

        return DmEnvToGym(obj, **options)
    if not is_env(obj):
        raise SourceError(
            f"`{argument}` {spec!r} returns a {type(obj).__name__}, not a gymnasium.Env, a dm_env.Environment or a "
            "TorchRL EnvBase."
        )
    close_quietly(obj)
    raise SourceError(
        f"`{argument}` {spec!r} returns a TorchRL {type(obj).__name__}; `record` and `sysid fit` can use "
        "its MuJoCo model, but this command needs a gymnasium env or a dm_env.Environment (or call "
        "sim2real.agents.train(env) from Python)."
    )


def make_user_env(source_id: str, **options: Any) -> gym.Env:
    """The gymnasium env of a ``model:<path>`` or ``env:<module>:<factory>`` id (what :func:`sim2real.make` calls).

    Raises:
        SourceError: an id without either prefix, or a source that gives no gymnasium env.
    """
    if source_id.startswith(MODEL_PREFIX):
        return build_model(source_id[len(MODEL_PREFIX) :], "--model", options)
    if source_id.startswith(ENV_PREFIX):
        spec = source_id[len(ENV_PREFIX) :]
        return as_gym(build_factory(spec, "--env"), spec, "--env", options)
    raise SourceError(f"`source_id` must start with {MODEL_PREFIX!r} or {ENV_PREFIX!r}. Received {source_id!r}.")
