"""A slice or range ``select`` is written to a randomiser config and read back equal (loose end 2 of session 11).

Before: ``dump_config`` refused ``select=slice(0, 12)`` (commit 090a454), so ``FitResult.to_randomizers(noise_select=
{"qpos": slice(0, 12)})`` could not be saved. Now a slice is written in Python's notation (``'0:12'``, ``'0:12:2'``)
and a range as Python prints it (``'range(6, 12)'``); ``load_config`` reads them back to the same ``slice``/``range``,
so each process keeps its random stream (named ``obs_noise[0:12]`` by ``selection_repr``) and draws bitwise the same
values on an env. The list of the same indices would not do: it names another stream and draws other values.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import sim2real as s2r
from noise_models import ActionNoise, Bias, Gaussian, ObservationNoise
from randomizers import Uniform, dump_config, load_config
from sim2real.mjcf_env import MjcfEnv

# a 6-hinge arm: the observation is qpos then qvel, 12 values
ARM = """<mujoco>
  <option timestep="0.005"/>
  <default><joint damping="0.2" axis="0 1 0" range="-2 2"/><geom type="capsule" size="0.03"/></default>
  <worldbody>
    <body name="l1"><joint name="j1" axis="0 0 1"/><geom fromto="0 0 0 0.2 0 0" mass="1.0"/>
      <body name="l2" pos="0.2 0 0"><joint name="j2"/><geom fromto="0 0 0 0.2 0 0" mass="0.8"/>
        <body name="l3" pos="0.2 0 0"><joint name="j3"/><geom fromto="0 0 0 0.15 0 0" mass="0.5"/>
          <body name="l4" pos="0.15 0 0"><joint name="j4" axis="1 0 0"/><geom fromto="0 0 0 0.1 0 0" mass="0.3"/>
            <body name="l5" pos="0.1 0 0"><joint name="j5"/><geom fromto="0 0 0 0.08 0 0" mass="0.2"/>
              <body name="l6" pos="0.08 0 0"><joint name="j6"/><geom fromto="0 0 0 0.05 0 0" mass="0.1"/></body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="j1"/><motor joint="j2"/><motor joint="j3"/><motor joint="j4"/><motor joint="j5"/><motor joint="j6"/>
  </actuator>
</mujoco>"""

SELECTS = {
    "slice": (slice(0, 6), "0:6"),
    "range": (range(6, 12), "range(6, 12)"),
    "stepped slice": (slice(1, 12, 3), "'1:12:3'"),  # quoted by yaml: unquoted, YAML 1.1 reads 1:12:3 as base 60
    "open slice": (slice(None, -4), ":-4"),
    "step of one": (slice(2, None, 1), "2::1"),
}


def _models(select: Any) -> list[Any]:
    # the select on the pipeline (its processes inherit it), on a process, and a range on the 6 actions
    return [
        ObservationNoise(Gaussian(std=Uniform(0.01, 0.1)), Bias(offset=Uniform(-0.05, 0.05), select=select)),
        ObservationNoise(Gaussian(std=Uniform(0.2, 0.3), name="wide"), select=select),
        ActionNoise(Gaussian(std=Uniform(0.01, 0.1), select=range(1, 4))),
    ]


def _run(models: list[Any]) -> tuple[np.ndarray, dict[str, float]]:
    env = s2r.wrap(MjcfEnv(xml=ARM), *models, seed=11)
    obs, info = env.reset(seed=11)
    trace = [obs]
    for k in range(5):
        obs, *_ = env.step(np.full(6, 0.1 * k))
        trace.append(obs)
    env.close()
    return np.stack(trace), dict(info["sim2real"]["params"])


@pytest.mark.parametrize("case", list(SELECTS))
def test_a_slice_or_range_select_round_trips_and_draws_the_same_values(case: str) -> None:
    select, written = SELECTS[case]
    models = _models(select)
    text = dump_config(models)
    assert f"select: {written}\n" in text, text
    loaded = load_config(text)
    assert loaded == models
    assert [m.select for m in loaded] == [None, select, None]
    assert type(loaded[1].select) is type(select) and loaded[1].select == select
    assert loaded[0].processes[1].select == select and loaded[2].processes[0].select == range(1, 4)
    (obs, drawn), (again, redrawn) = _run(models), _run(loaded)
    assert obs.tobytes() == again.tobytes()
    assert drawn == redrawn and len(drawn) > 0
    assert dump_config(loaded) == text


def test_the_list_of_the_same_indices_would_draw_other_values() -> None:
    """Why the export keeps the slice: the stream is named by the selection (obs_wide[0:6] vs obs_wide[0,1,2,3,4,5])."""
    (_, by_slice), (_, by_list) = _run(_models(slice(0, 6))), _run(_models(list(range(6))))
    key = "obs_wide_std[0]"
    assert key in by_slice and key in by_list and by_slice[key] != by_list[key]


@pytest.mark.parametrize(
    "bad",
    ["0:x", "1:2:3:4", "0:12:0", "range(0, 12", "range(0, 12, 0)", "range()", "range(a)", "0 12:"],
)
def test_a_malformed_slice_string_is_refused_naming_where_what_and_what_was_received(bad: str) -> None:
    text = (
        f"signals:\n  - type: ObservationNoise\n    processes:\n      - {{type: Gaussian, std: 0.1, select: '{bad}'}}\n"
    )
    with pytest.raises(ValueError) as err:
        load_config(text)
    assert str(err.value) == (
        "<config>: signals[0].processes[0]: `select` must be observation keys, an index, a list of indices, a slice "
        "written 'start:stop' or 'start:stop:step' (integers, each may be left out, step not 0: '0:12', ':6', "
        f"'0:12:2') or a range written 'range(start, stop)' or 'range(start, stop, step)'. Received {bad!r}."
    )
    top = f"signals:\n  - type: ActionLatency\n    steps: 1\n    select: '{bad}'\n"
    with pytest.raises(ValueError) as err:
        load_config(top)
    assert str(err.value).startswith("<config>: signals[0]: `select` must be observation keys,")
    assert str(err.value).endswith(f"Received {bad!r}.")


def test_key_names_and_index_lists_load_as_before() -> None:
    loaded = load_config(
        "signals:\n  - type: ObservationNoise\n    select: velocity\n    processes:\n"
        "      - {type: Gaussian, std: 0.1, select: [0, 2]}\n      - {type: Bias, offset: 0.1, select: 'pos*'}\n"
    )
    assert loaded == [
        ObservationNoise(Gaussian(std=0.1, select=[0, 2]), Bias(offset=0.1, select="pos*"), select="velocity")
    ]
