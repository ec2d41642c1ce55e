"""Where an env comes from: a task id, an MJCF file or an env factory — the one owner of ``--task``/``--model``/``--env``.

Every command that runs an env (``record``, ``sysid fit``, ``train``, ``evaluate``, ``visualize``) and the
study/evaluation YAML resolve their env through :func:`resolve_source`, which returns a :class:`Source`. A source
has an :attr:`~Source.id` that :func:`sim2real.make` accepts, so it travels through checkpoints, specs and worker
processes like a task id:

* ``--task dmc/reacher-easy`` — a registered task (``sim2real tasks``) or ``gym/<id>``; the id is itself.
* ``--model robot.xml`` — an MJCF file, run by :class:`sim2real.mjcf_env.MjcfEnv`; the id is
  ``model:<absolute path>``.
* ``--env package.module:factory`` — a callable returning a gymnasium env or a ``dm_env.Environment`` (adapted by
  :class:`sim2real.DmEnvToGym`); a TorchRL ``EnvBase`` serves the commands that only need its MuJoCo model
  (``record``, ``sysid fit``). The id is ``env:package.module:factory``.

The building half (an MJCF file or a factory into an env) lives in :mod:`sim2real.user_envs`, which
:func:`sim2real.make` calls, so the task registry and this module do not import each other.

Bad input fails with :class:`SourceError` (a ``ValueError``) naming the argument, what is allowed and what was
received: a missing file, an MJCF that does not compile (MuJoCo's message quoted), a module that does not import,
a factory that is missing, raises or returns something that is not an env.

Example:
    >>> import os, tempfile
    >>> path = os.path.join(tempfile.mkdtemp(), "arm.xml")
    >>> _ = open(path, "w").write('<mujoco><worldbody><body><joint name="j"/><geom size=".1"/></body>'
    ...                           '</worldbody><actuator><motor joint="j" ctrlrange="-1 1"/></actuator></mujoco>')
    >>> source = resolve_source(model=path)
    >>> source.kind, source.id == "model:" + path
    ('model', True)
    >>> import sim2real
    >>> sim2real.make(source.id).action_space.shape
    (1,)
    >>> resolve_source(task="dmc/reacher-easy", model=path)
    Traceback (most recent call last):
    ...
    sim2real.user_envs.SourceError: give one of --task, --model and --env. Received --task and --model.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco

from sim2real.user_envs import (
    ENV_PREFIX,
    MODEL_PREFIX,
    SourceError,
    as_gym,
    build_factory,
    build_model,
    close_quietly,
    import_factory,
    make_user_env,
)

__all__ = [
    "ENV_PREFIX",
    "KINDS",
    "MODEL_PREFIX",
    "Source",
    "SourceError",
    "make_source_env",
    "open_source",
    "parse_source_id",
    "resolve_source",
    "source_from_config",
]

#: The source kinds, in the order the arguments are listed.
KINDS: tuple[str, ...] = ("task", "model", "env")


@dataclass(frozen=True)
class Source:
    """A resolved env source.

    Attributes:
        kind: ``"task"``, ``"model"`` or ``"env"``.
        value: the task id, the MJCF file's absolute path or ``"package.module:factory"``.
        argument: how the user named it (``--model``, ``model``), used in error messages.
    """

    kind: str
    value: str
    argument: str = ""

    @property
    def id(self) -> str:
        """What :func:`sim2real.make` takes: the task id, ``model:<path>`` or ``env:<module>:<factory>``."""
        if self.kind == "task":
            return self.value
        return (MODEL_PREFIX if self.kind == "model" else ENV_PREFIX) + self.value

    @property
    def label(self) -> str:
        """A short name for messages and titles: the task id, the file name or the factory."""
        return Path(self.value).name if self.kind == "model" else self.value

    def _arg(self) -> str:
        return self.argument or f"--{self.kind}"

    def check(self) -> None:
        """Fails early (:class:`SourceError`) when the source cannot give an env; builds and closes one."""
        close_quietly(self._build({}))

    def _build(self, options: Mapping[str, Any]) -> Any:
        """The raw object: a gymnasium env (task, model) or what the factory returned (checked to be an env)."""
        if self.kind == "task":
            from sim2real.tasks import make

            try:
                return make(self.value, **options)
            except (TypeError, ValueError) as err:
                raise SourceError(f"`{self._arg()}`: {err}") from err
        if self.kind == "model":
            return build_model(self.value, self._arg(), options)
        return build_factory(self.value, self._arg())

    def make(self, **options: Any) -> gym.Env:
        """A gymnasium env of this source (dm_env factories adapted by :class:`sim2real.DmEnvToGym`).

        Args:
            **options: for a task, what :func:`sim2real.make` takes; for a model, :class:`MjcfEnv`'s
                ``render_mode``, ``width``, ``height``, ``max_episode_steps``, ``control_timestep``,
                ``reset_noise``; for a dm_env factory, :class:`DmEnvToGym`'s options.

        Raises:
            SourceError: the source gives no env, or a TorchRL env (which has no gymnasium view).
        """
        if self.kind != "env":
            return self._build(options)
        return as_gym(self._build({}), self.value, self._arg(), options)


def resolve_source(
    task: str | None = None,
    model: str | os.PathLike[str] | None = None,
    env: str | None = None,
    *,
    default_task: str | None = None,
    base: str | os.PathLike[str] | None = None,
    arguments: tuple[str, str, str] = ("--task", "--model", "--env"),
) -> Source:
    """The one :class:`Source` named by at most one of ``task``, ``model`` and ``env``.

    Args:
        task: a task id.
        model: an MJCF file (relative paths are taken from ``base``, default the working folder); it must exist
            and compile.
        env: ``"package.module:factory"``; its module must import (from ``sys.path``, the working folder or
            ``base``) and the factory exist (it is not called here).
        default_task: used when none is given; None makes one of them required.
        base: the folder relative model paths start from (a spec file's folder).
        arguments: how the three are named in messages (``("task", "model", "env")`` for YAML keys).

    Raises:
        SourceError: none or several given, a missing or invalid MJCF, a factory that does not import.
    """
    given = [(arg, value) for arg, value in zip(arguments, (task, model, env), strict=True) if value is not None]
    if len(given) > 1:
        raise SourceError(
            f"give one of {', '.join(arguments[:2])} and {arguments[2]}. Received {' and '.join(a for a, _ in given)}."
        )
    if not given:
        if default_task is None:
            raise SourceError(f"give one of {', '.join(arguments[:2])} and {arguments[2]}. Received none.")
        return Source("task", default_task, arguments[0])
    if task is not None:
        if not isinstance(task, str) or not task:
            raise SourceError(f"`{arguments[0]}` must be a task id such as 'dmc/reacher-easy'. Received {task!r}.")
        if task.startswith((MODEL_PREFIX, ENV_PREFIX)):
            return parse_source_id(task)
        return Source("task", task, arguments[0])
    if model is not None:
        if not isinstance(model, (str, os.PathLike)) or not os.fspath(model):
            raise SourceError(f"`{arguments[1]}` must be the path of an MJCF file. Received {model!r}.")
        path = Path(model)
        if not path.is_absolute():
            path = Path(base if base is not None else os.getcwd()) / path
        if not path.is_file():
            raise SourceError(f"`{arguments[1]}` {os.fspath(model)!r} does not exist (looked for {str(path)!r}).")
        source = Source("model", str(path.resolve()), arguments[1])
        try:
            mujoco.MjModel.from_xml_path(source.value)
        except ValueError as err:
            raise SourceError(
                f"`{arguments[1]}` {os.fspath(model)!r} is not a valid MJCF model: {' '.join(str(err).split())}"
            ) from err
        return source
    if not isinstance(env, str):
        raise SourceError(f"`{arguments[2]}` must look like 'package.module:factory'. Received {env!r}.")
    import_factory(env, arguments[2], base=base)  # a module beside the spec is found too
    return Source("env", env, arguments[2])


def parse_source_id(text: str) -> Source:
    """The :class:`Source` behind an id (``model:<path>``, ``env:<module>:<factory>`` or a task id); nothing is
    checked or loaded.

    Example:
        >>> parse_source_id("env:my_robot.envs:make_env")
        Source(kind='env', value='my_robot.envs:make_env', argument='')
    """
    if text.startswith(MODEL_PREFIX):
        return Source("model", text[len(MODEL_PREFIX) :])
    if text.startswith(ENV_PREFIX):
        return Source("env", text[len(ENV_PREFIX) :])
    return Source("task", text)


def make_source_env(source_id: str, **options: Any) -> gym.Env:
    """The gymnasium env of a ``model:``/``env:`` id (:func:`sim2real.user_envs.make_user_env`, which
    :func:`sim2real.make` calls for those ids)."""
    return make_user_env(source_id, **options)


def open_source(source: Source) -> tuple[Any, Any]:
    """``(env, handle)``: the raw env object of ``source`` and its :class:`sim2real.PhysicsHandle`.

    A TorchRL env is accepted here (only its MuJoCo model and data are used). The caller closes ``env``.

    Raises:
        SourceError: the source gives no env, or an env without a MuJoCo model.
    """
    from sim2real.physics import find_physics

    obj = source._build({})
    handle = find_physics(obj)  # owner: the env that holds the model, under any TorchRL wrapper
    if handle is None:
        close_quietly(obj)
        raise SourceError(
            f"`{source._arg()}` {source.value!r} gives a {type(obj).__name__} with no MuJoCo model inside "
            "(sim2real looks for model/data attributes, dm-control physics and the wrappers' inner envs)."
        )
    return obj, handle


def source_from_config(config: Mapping[str, Any], where: str, base: str | os.PathLike[str] | None) -> Source:
    """The source of a study/evaluation YAML: exactly one of the keys ``task``, ``model`` (a path relative to the
    YAML file) and ``env``.

    Raises:
        SourceError: none or several keys, or a source that does not resolve; the message starts with ``where``.
    """
    try:
        return resolve_source(
            config.get("task"),
            config.get("model"),
            config.get("env"),
            base=base,
            arguments=KINDS,  # type: ignore[arg-type]
        )
    except SourceError as err:
        raise SourceError(f"{where}: {err}") from err
