"""``as_policy``: one batched numpy interface ``(B, obs_dim) -> (B, act_dim)`` for every kind of policy.

Accepted: a TorchRL policy module (``TensorDictModuleBase`` reading one observation key), a plain
``torch.nn.Module`` on tensors, a checkpoint path or :class:`~sim2real.agents.Checkpoint`, a
:class:`~sim2real.agents.TrainResult`, a scripted baseline, or any callable ``obs -> action``.
Stochastic TorchRL policies run in deterministic mode (the mean action).

Example:
    >>> import numpy as np
    >>> from sim2real.agents import ReachController
    >>> policy = as_policy(ReachController())
    >>> policy(np.zeros((4, 16), dtype=np.float32)).shape
    (4, 3)
    >>> as_policy(lambda obs: obs[:2] * 2)(np.ones((3, 5))).tolist()
    [[2.0, 2.0], [2.0, 2.0], [2.0, 2.0]]
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["BatchedPolicy", "as_policy"]


class BatchedPolicy:
    """A batched numpy policy: ``policy(obs)`` with ``obs`` of shape ``(B, obs_dim)`` gives ``(B, act_dim)``
    float32 actions; a single ``(obs_dim,)`` observation gives ``(act_dim,)``.

    Attributes:
        name: what the policy was made from (for reports).
        source: the original object.
    """

    def __init__(self, fn: Callable[[np.ndarray], np.ndarray], name: str, source: Any) -> None:
        self._fn = fn
        self.name = name
        self.source = source

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Actions for a batch ``(B, obs_dim)`` or one observation ``(obs_dim,)``."""
        arr = np.asarray(obs)
        if arr.ndim not in (1, 2):
            raise ValueError(f"`obs` must have shape (obs_dim,) or (B, obs_dim). Received shape {arr.shape}.")
        batch = arr[None] if arr.ndim == 1 else arr
        out = np.asarray(self._fn(batch), dtype=np.float32)
        if out.ndim == 1 and batch.shape[0] == 1:
            out = out[None]
        if out.ndim != 2 or out.shape[0] != batch.shape[0]:
            raise ValueError(
                f"policy {self.name} returned actions of shape {out.shape} for {batch.shape[0]} observation(s); "
                "expected (B, act_dim)."
            )
        return out[0] if arr.ndim == 1 else out

    def __repr__(self) -> str:
        return f"BatchedPolicy({self.name})"


def _tanh_normal_fast_path(
    module: Any, key: str, out_key: str, dtype: Any
) -> Callable[[np.ndarray], np.ndarray] | None:
    """For a ``ProbabilisticActor`` with a ``TanhNormal`` head (what ``sim2real.agents`` trains): the deterministic
    action computed from the network and the distribution's own transforms, without building a TensorDict and a
    distribution per call (those cost ~0.3 ms a call, more than the MLP). Used only after checking that it gives
    bitwise the same actions as the TorchRL path on a probe batch; otherwise None."""
    import torch
    from tensordict import TensorDict
    from tensordict.nn import TensorDictModule
    from torchrl.envs.utils import ExplorationType, set_exploration_type
    from torchrl.modules import ProbabilisticActor, TanhNormal

    if not isinstance(module, ProbabilisticActor) or key != "observation" or out_key != "action":
        return None
    try:
        inner, head = module.module[0], module.module[-1]
        kwargs = dict(head.distribution_kwargs or {})
        if len(module.module) != 2 or head.distribution_class is not TanhNormal:
            return None
        if not isinstance(inner, TensorDictModule):
            return None
        if list(inner.out_keys) != ["loc", "scale"] or list(inner.in_keys) != [key]:
            return None
        net = inner.module
        from sim2real.agents.nets import Normalize

        # The observation width: the normaliser's (its angle features widen the first Linear), else the Linear's.
        first = next(m for m in net.modules() if isinstance(m, (Normalize, torch.nn.Linear)))
        width = first.loc.numel() if isinstance(first, Normalize) else first.in_features
        probe = torch.randn(7, int(width))
        probe = probe.to(dtype)
        with torch.no_grad():
            loc, scale = net(probe)
            transforms = TanhNormal(loc, scale, **kwargs).transforms
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            slow = module(TensorDict({key: probe}, batch_size=[7]))[out_key]
    except Exception:
        return None

    def fn(batch: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            action, _ = net(torch.as_tensor(np.ascontiguousarray(batch), dtype=dtype))
            for t in transforms:
                action = t(action)
        return action.numpy()

    flat = _flat_mean_action(net, transforms, dtype)
    if flat is not None and np.array_equal(flat(probe.numpy()), slow.numpy()):
        return flat
    return fn if np.array_equal(fn(probe.numpy()), slow.numpy()) else None


def _safe_tanh(lim: float) -> Callable[[Any], Any]:
    def forward(x: Any) -> Any:
        return x.tanh().clamp(-lim, lim)

    return forward


def _flat_mean_action(net: Any, transforms: list[Any], dtype: Any) -> Callable[[np.ndarray], np.ndarray] | None:
    """The deterministic action of ``build_actor``'s SAC network (``Sequential(Normalize, MLP,
    NormalParamExtractor)``) then ``transforms``, as one function of the same torch kernels: the layers called
    directly instead of through ``nn.Module.__call__`` (10 calls a forward), the scale head skipped (the mean
    action reads only ``loc``), and TorchRL's ``SafeTanhTransform`` as its forward (tanh, then the clamp to
    ``1 - resolution``) instead of an autograd ``Function`` that inspects its own signature on every call (~0.1 ms).
    None for any other layout; the caller keeps it only if it gives bitwise the TorchRL path's actions."""
    import torch
    from tensordict.nn import NormalParamExtractor
    from torch import nn

    from sim2real.agents.nets import Normalize

    try:
        from torchrl.modules.distributions.continuous import SafeTanhTransform
    except ImportError:  # pragma: no cover - another torchrl layout
        return None
    if not isinstance(net, nn.Sequential) or len(net) != 3:
        return None
    norm, mlp, head = net
    if type(norm) is not Normalize or type(head) is not NormalParamExtractor or not isinstance(mlp, nn.Sequential):
        return None
    layers: list[tuple[Any, ...]] = []
    for m in mlp:
        if type(m) is nn.Linear:
            layers.append((torch._C._nn.linear, m.weight, m.bias))
        elif type(m) is nn.ReLU and not m.inplace:
            layers.append((torch.relu,))
        elif type(m) is nn.Tanh:
            layers.append((torch.tanh,))
        else:
            return None
    steps: list[Callable[[Any], Any]] = []
    for t in transforms:
        if type(t) is SafeTanhTransform:
            steps.append(_safe_tanh(1.0 - torch.finfo(dtype).resolution))
        else:
            steps.append(t)
    normalize = norm.forward

    def flat(batch: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            x = normalize(torch.as_tensor(np.ascontiguousarray(batch), dtype=dtype))
            for layer in layers:
                x = layer[0](x, *layer[1:])
            action = x.chunk(2, -1)[0]
            for step in steps:
                action = step(action)
        return action.numpy()

    return flat


def _torchrl_fn(module: Any) -> Callable[[np.ndarray], np.ndarray]:
    import torch
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    keys = [k for k in module.in_keys if k not in ("is_init",)]
    if len(keys) != 1:
        raise TypeError(f"`policy` must read a single observation key to be batched. Received in_keys {keys}.")
    key = keys[0]
    out_key = "action" if "action" in module.out_keys else module.out_keys[0]
    dtype = next((p.dtype for p in module.parameters()), torch.float32)
    fast = _tanh_normal_fast_path(module, key, out_key, dtype)
    if fast is not None:
        return fast

    def fn(batch: np.ndarray) -> np.ndarray:
        obs = torch.as_tensor(np.ascontiguousarray(batch), dtype=dtype)
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            td = module(TensorDict({key: obs}, batch_size=[obs.shape[0]]))
        return td[out_key].detach().cpu().numpy()

    return fn


def _torch_fn(module: Any) -> Callable[[np.ndarray], np.ndarray]:
    import torch

    dtype = next((p.dtype for p in module.parameters()), torch.float32)

    def fn(batch: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            out = module(torch.as_tensor(np.ascontiguousarray(batch), dtype=dtype))
        return out.detach().cpu().numpy()

    return fn


def _rowwise(fn: Callable[[np.ndarray], Any]) -> Callable[[np.ndarray], np.ndarray]:
    def batched(batch: np.ndarray) -> np.ndarray:
        return np.stack([np.asarray(fn(row), dtype=np.float32) for row in batch])

    return batched


def as_policy(obj: Any, *, batched: bool | None = None, task: str | None = None) -> BatchedPolicy:
    """Turns ``obj`` into a :class:`BatchedPolicy`.

    Args:
        obj: a TorchRL policy module, a ``torch.nn.Module``, a checkpoint path (str or ``PathLike``), a
            :class:`~sim2real.agents.Checkpoint`, a :class:`~sim2real.agents.TrainResult`, a scripted
            baseline, or a callable ``obs -> action``.
        batched: for plain callables, whether they take a ``(B, obs_dim)`` batch; by default the
            callable's ``batched`` attribute, else False (called once per row).
        task: for checkpoints, the task the policy must have been trained on.

    Raises:
        TypeError: ``obj`` is none of the above.
        CheckpointError: an unreadable checkpoint or one trained on another task.
    """
    if isinstance(obj, BatchedPolicy):
        return obj
    if isinstance(obj, (str, os.PathLike)):
        from sim2real.agents.checkpoint import load_checkpoint

        ckpt = load_checkpoint(obj, task=task)
        return BatchedPolicy(_torchrl_fn(ckpt.policy), f"checkpoint {Path(obj).name} ({ckpt.run_id})", ckpt)
    kind = type(obj).__name__
    if kind in ("Checkpoint", "TrainResult") and hasattr(obj, "policy") and hasattr(obj, "run_id"):
        return BatchedPolicy(_torchrl_fn(obj.policy), f"{kind.lower()} {obj.run_id}", obj)
    import sys

    if "torch" in sys.modules:
        import torch
        from tensordict.nn import TensorDictModuleBase

        if isinstance(obj, TensorDictModuleBase):
            return BatchedPolicy(_torchrl_fn(obj), f"TorchRL {kind}", obj)
        if isinstance(obj, torch.nn.Module):
            return BatchedPolicy(_torch_fn(obj), f"torch {kind}", obj)
    if callable(obj):
        is_batched = bool(getattr(obj, "batched", False)) if batched is None else bool(batched)
        fn = obj if is_batched else _rowwise(obj)
        return BatchedPolicy(fn, kind if kind == "function" else repr(obj), obj)
    raise TypeError(
        "`obj` must be a TorchRL policy module, a torch.nn.Module, a checkpoint path, a Checkpoint, a TrainResult, "
        f"a scripted baseline or a callable obs -> action. Received {kind}."
    )
