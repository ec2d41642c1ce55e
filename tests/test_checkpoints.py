"""Tampered, foreign and mismatched checkpoints: one ``CheckpointError`` naming the file and the key, raised when
the checkpoint is loaded; ``sim2real evaluate`` reports it with exit 2 and one line before any worker starts.

Every case edits a copy of a checkpoint the package ships (``torch.load`` -> change one key -> ``torch.save``).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

torch = pytest.importorskip("torch")

from sim2real import cli  # noqa: E402
from sim2real.agents.checkpoint import CheckpointError, load_checkpoint  # noqa: E402

SHIPPED = Path(__file__).resolve().parents[1] / "sim2real/data/study/dmc-reacher-easy/checkpoints/nominal.pt"
TASK = "dmc/reacher-easy"
ARCH = "does not match its architecture: weight"

Edit = Callable[[dict[str, Any]], object]


def _set(key: str, value: Any) -> Edit:
    return lambda data: data.__setitem__(key, value)


def _del(key: str) -> Edit:
    return lambda data: data.pop(key)


def _config(key: str, value: Any) -> Edit:
    return lambda data: data["config"].__setitem__(key, value)


def _bounds(low: Any, high: Any) -> Edit:
    return lambda data: data.update(action_low=low, action_high=high)


#: (case id, the edit, the message after "checkpoint '<file>'")
CASES: list[tuple[str, Edit, str]] = [
    ("obs_dim negative", _set("obs_dim", -3), ": `obs_dim` must be an int >= 1. Received -3."),
    ("obs_dim zero", _set("obs_dim", 0), ": `obs_dim` must be an int >= 1. Received 0."),
    ("obs_dim float", _set("obs_dim", 6.5), ": `obs_dim` must be an int >= 1. Received 6.5."),
    ("obs_dim whole float", _set("obs_dim", 6.0), ": `obs_dim` must be an int >= 1. Received 6.0."),
    ("obs_dim bool", _set("obs_dim", True), ": `obs_dim` must be an int >= 1. Received True."),
    ("obs_dim str", _set("obs_dim", "6"), ": `obs_dim` must be an int >= 1. Received '6'."),
    ("obs_dim None", _set("obs_dim", None), ": `obs_dim` must be an int >= 1. Received None."),
    ("obs_dim other", _set("obs_dim", 7), f" {ARCH} 'module.0.module.0.loc' has shape (6,), expected (7,)."),
    (
        "bounds swapped",
        _bounds([1.0, 1.0], [-1.0, -1.0]),
        ": `action_low` must be < `action_high` in every entry. Received 1.0 >= -1.0 at index 0.",
    ),
    (
        "bounds equal",
        _bounds([-1.0, 0.5], [1.0, 0.5]),
        ": `action_low` must be < `action_high` in every entry. Received 0.5 >= 0.5 at index 1.",
    ),
    (
        "bounds lengths differ",
        _bounds([-1.0, -1.0, -1.0], [1.0, 1.0]),
        ": `action_low` and `action_high` must have the same length. Received 3 and 2.",
    ),
    (
        "bounds too long",
        _bounds([-1.0] * 3, [1.0] * 3),
        f" {ARCH} 'module.0.module.1.4.weight' has shape (4, 128), expected (6, 128).",
    ),
    (
        "bounds too short",
        _bounds([-1.0], [1.0]),
        f" {ARCH} 'module.0.module.1.4.weight' has shape (4, 128), expected (2, 128).",
    ),
    (
        "bounds empty",
        _bounds([], []),
        ": `action_low` must be a non-empty list of finite numbers. Received [].",
    ),
    (
        "bounds nan",
        _bounds([float("nan"), -1.0], [1.0, 1.0]),
        ": `action_low` must be a non-empty list of finite numbers. Received [nan, -1.0].",
    ),
    (
        "bounds infinite",
        _bounds([-1.0, -1.0], [1.0, float("inf")]),
        ": `action_high` must be a non-empty list of finite numbers. Received [1.0, inf].",
    ),
    (
        "bounds str",
        _bounds("-1", [1.0, 1.0]),
        ": `action_low` must be a non-empty list of finite numbers. Received '-1'.",
    ),
    (
        "bounds of str",
        _bounds([-1.0, -1.0], ["1", "1"]),
        ": `action_high` must be a non-empty list of finite numbers. Received ['1', '1'].",
    ),
    (
        "bounds tensor",
        _bounds(torch.tensor([-1.0, -1.0]), [1.0, 1.0]),
        ": `action_low` must be a non-empty list of finite numbers. Received tensor([-1., -1.]).",
    ),
    ("task int", _set("task", 7), ": `task` must be a str or None. Received 7."),
    ("algo unknown", _set("algo", "dqn"), ": `algo` must be one of ['ppo', 'sac']. Received 'dqn'."),
    ("algo int", _set("algo", 3), ": `algo` must be a str. Received 3."),
    (
        "algo other",
        _set("algo", "ppo"),
        " config: `algo` must be 'ppo' for PPOConfig. Received 'sac'.",
    ),
    ("config list", _set("config", [1, 2]), ": `config` must be a mapping. Received [1, 2]."),
    ("config bad value", _config("lr", -1.0), " config: `lr` must be > 0. Received -1.0."),
    (
        "config hidden sizes",
        _config("hidden_sizes", "x"),
        " config: `hidden_sizes` must be a non-empty tuple of positive ints. Received 'x'.",
    ),
    (
        "config other architecture",
        _config("hidden_sizes", [64]),
        " does not match its architecture: missing weights [], unexpected weights ['module.0.module.1.4.bias', "
        "'module.0.module.1.4.weight'].",
    ),
    ("seed negative", _set("seed", -1), ": `seed` must be an int >= 0. Received -1."),
    ("seed str", _set("seed", "0"), ": `seed` must be an int >= 0. Received '0'."),
    ("run_id None", _set("run_id", None), ": `run_id` must be a str. Received None."),
    ("git_commit int", _set("git_commit", 5), ": `git_commit` must be a str or None. Received 5."),
    ("versions list", _set("versions", ["torch"]), ": `versions` must be a mapping. Received ['torch']."),
    ("effects int", _set("effects", 3), ": `effects` must be a str or None. Received 3."),
    ("state_dict list", _set("state_dict", [1]), ": `state_dict` must be a mapping of names to tensors. Received [1]."),
    (
        "state_dict values",
        lambda data: data["state_dict"].__setitem__("module.0.module.0.loc", [0.0] * 6),
        ": `state_dict` must map names to tensors.",
    ),
    (
        "weights nan",
        lambda data: data["state_dict"]["module.0.module.1.0.bias"].fill_(float("nan")),
        ": weight 'module.0.module.1.0.bias' holds NaN or infinite values.",
    ),
    (
        "weight missing",
        lambda data: data["state_dict"].pop("module.0.module.1.4.bias"),
        " does not match its architecture: missing weights ['module.0.module.1.4.bias'], unexpected weights [].",
    ),
    ("missing obs_dim", _del("obs_dim"), " is missing key(s) ['obs_dim']."),
    (
        "missing bounds",
        lambda d: (d.pop("action_low"), d.pop("action_high")),
        " is missing key(s) ['action_low', 'action_high'].",
    ),
    ("format_version", _set("format_version", 2), " has format_version 2; this sim2real reads 1."),
    (
        "format",
        _set("format", "other"),
        " is not a sim2real.agents checkpoint (no 'sim2real.agents.checkpoint' marker).",
    ),
]


@pytest.fixture(scope="module")
def shipped() -> dict[str, Any]:
    return torch.load(SHIPPED, map_location="cpu", weights_only=True)


def _tampered(shipped: dict[str, Any], edit: Edit, path: Path) -> Path:
    data = copy.deepcopy(shipped)
    edit(data)
    torch.save(data, path)
    return path


@pytest.mark.parametrize(("case", "edit", "message"), CASES, ids=[c for c, _, _ in CASES])
def test_tampered_checkpoint_is_one_checkpoint_error(
    case: str, edit: Edit, message: str, shipped: dict[str, Any], tmp_path: Path
) -> None:
    path = _tampered(shipped, edit, tmp_path / "bad.pt")
    with pytest.raises(CheckpointError) as raised:
        load_checkpoint(path)
    assert str(raised.value) == f"checkpoint {str(path)!r}{message}"


def test_the_shipped_checkpoint_loads(shipped: dict[str, Any], tmp_path: Path) -> None:
    path = _tampered(shipped, lambda data: None, tmp_path / "same.pt")
    assert load_checkpoint(path, task=TASK).task == TASK


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "is corrupt or not a torch file (EOFError)."),
        (None, "is not a sim2real.agents checkpoint (no 'sim2real.agents.checkpoint' marker)."),
    ],
)
def test_foreign_files(content: bytes | None, message: str, tmp_path: Path) -> None:
    path = tmp_path / "foreign.pt"
    if content is None:
        torch.save([1, 2, 3], path)
    else:
        path.write_bytes(content)
    with pytest.raises(CheckpointError) as raised:
        load_checkpoint(path)
    assert str(raised.value) == f"checkpoint {str(path)!r} {message}"


def test_wrong_task(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError) as raised:
        load_checkpoint(SHIPPED, task="sim2real/arm-reach")
    assert str(raised.value) == (
        f"checkpoint {str(SHIPPED)!r} was trained on task 'dmc/reacher-easy', not on 'sim2real/arm-reach'."
    )


# ---------------------------------------------------------------------------------- sim2real evaluate

EVALUATE_CASES = [
    ("obs_dim negative", TASK, _set("obs_dim", -3), ": `obs_dim` must be an int >= 1. Received -3."),
    (
        "bounds swapped",
        TASK,
        _bounds([1.0, 1.0], [-1.0, -1.0]),
        ": `action_low` must be < `action_high` in every entry. Received 1.0 >= -1.0 at index 0.",
    ),
    (
        "bounds too long",
        TASK,
        _bounds([-1.0] * 3, [1.0] * 3),
        f" {ARCH} 'module.0.module.1.4.weight' has shape (4, 128), expected (6, 128).",
    ),
    ("missing key", TASK, _del("state_dict"), " is missing key(s) ['state_dict']."),
    (
        "no task, other sizes",
        "sim2real/arm-reach",
        _set("task", None),
        " takes observations of size 6 and gives actions of size 2; task 'sim2real/arm-reach' has 16 and 3.",
    ),
    (
        "wrong task",
        "sim2real/arm-reach",
        lambda data: None,
        " was trained on task 'dmc/reacher-easy', not on 'sim2real/arm-reach'.",
    ),
]


@pytest.mark.parametrize(("case", "task", "edit", "message"), EVALUATE_CASES, ids=[c for c, *_ in EVALUATE_CASES])
def test_evaluate_refuses_a_bad_checkpoint_before_workers_start(
    case: str,
    task: str,
    edit: Edit,
    message: str,
    shipped: dict[str, Any],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    import sim2real.evaluation as evaluation

    def no_workers(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("workers were started")

    monkeypatch.setattr(evaluation, "_dispatch", no_workers)
    checkpoint = _tampered(shipped, edit, tmp_path / "ppo.pt")
    spec = tmp_path / "spec.yaml"
    spec.write_text(f"task: {task}\nepisodes: 1\nmax_steps: 2\npolicies: {{ppo: {{checkpoint: ppo.pt}}}}\n")
    out = tmp_path / "report"
    assert cli.main(["evaluate", "--config", str(spec), "--out", str(out), "--backend", "local", "--quiet"]) == 2
    captured = capsys.readouterr()
    assert captured.err == f"sim2real evaluate: error: checkpoint {str(checkpoint)!r}{message}\n"
    assert captured.out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ppo.pt", "spec.yaml"]  # no report folder


def test_a_checkpoint_without_its_task_loads_for_any_task(shipped: dict[str, Any], tmp_path: Path) -> None:
    path = _tampered(shipped, _set("task", None), tmp_path / "anonymous.pt")
    assert load_checkpoint(path, task=TASK).task is None  # its sizes are checked where it is used (evaluate)
