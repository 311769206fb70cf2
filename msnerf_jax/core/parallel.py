"""Data parallelism over devices (and processes): a 1-D mesh on the axis "batch", steps run
under `jax.shard_map` (or `jax.pmap`), and the host-side moves in and out of it.

A step function is written once, per device, with an `axis_name` and `lax.pmean` (see
train/nerf.train_step). `DataParallel.compile` runs it

- on one device: `jax.jit` (axis_name None, no collectives);
- under `shard_map` (the default): over a `Mesh` of every device of every process
  (`jax.distributed`), the batch split along its leading axis, the state and the constants
  replicated: global `jax.Array`s, so the same program serves one process or several;
- under `pmap` (`mode="pmap"`): over this process's devices, with the leading device axis
  of pmap's replicated state; the same result, kept as a switch.

Every process computes the same global batch from (seed, step); `put_batch` hands each
device its rows of it, so a step's result does not depend on how many processes and
devices share it.
"""

import dataclasses
import functools
from typing import Any, Callable, Optional, Sequence, Tuple

import flax
import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from msnerf_jax.core.errors import UserError

AXIS = "batch"
MODES = ("shard_map", "pmap")


def data_mesh(n_devices: Optional[int] = None) -> Mesh:
  """A 1-D mesh on AXIS: with several processes (jax.distributed), every device of every
  process; with one, its first `n_devices` devices (default all).

  UserError when `n_devices` is more than there are (or, with several processes, not all
  of them: each process brings its own devices).
  """
  if jax.process_count() > 1:
    if n_devices not in (None, jax.device_count()):
      raise UserError(f"{n_devices} devices asked for: with {jax.process_count()} processes "
                      f"training uses all {jax.device_count()} devices of all of them")
    return Mesh(np.array(jax.devices()), (AXIS,))
  local = jax.local_devices()
  n = len(local) if n_devices is None else n_devices
  if not 1 <= n <= len(local):
    raise UserError(f"{n} devices asked for; this machine has {len(local)} "
                    f"({local[0].platform})")
  return Mesh(np.array(local[:n]), (AXIS,))


def local_mesh() -> Mesh:
  """A 1-D mesh on AXIS of this process's devices (what rendering uses by default)."""
  return Mesh(np.array(jax.local_devices()), (AXIS,))


def _global(tree, sharding: NamedSharding):
  """Host values (the same on every process) as global arrays of `sharding`: each process
  places only its own devices' pieces."""
  if jax.process_count() == 1:
    return jax.device_put(tree, sharding)

  def place(x):
    x = np.asarray(x)
    return jax.make_array_from_callback(x.shape, sharding, lambda index: x[index])
  return jax.tree_util.tree_map(place, tree)


def replicated(tree, mesh: Mesh):
  """`tree` (the same on every process) as global arrays on every device of `mesh`."""
  return _global(tree, NamedSharding(mesh, PartitionSpec()))


def split_rows(tree, mesh: Mesh, axis: int = 0):
  """`tree` (the same on every process) as global arrays split along `axis` (divisible by
  the mesh's size) over the devices of `mesh`, in order."""
  return _global(tree, NamedSharding(mesh, PartitionSpec(*(None,) * axis, AXIS)))


def _local_copy(x):
  """A numpy copy of a replicated array (one of this process's copies)."""
  if isinstance(x, jax.Array) and not x.is_fully_addressable:
    return np.asarray(x.addressable_shards[0].data)
  return np.asarray(x)


def gather(tree):
  """Numpy copies of arrays split across the devices of every process, whole, on every
  process (a collective: every process calls it)."""
  if jax.process_count() == 1:
    return jax.tree_util.tree_map(np.asarray, tree)
  return multihost_utils.process_allgather(tree, tiled=True)


@dataclasses.dataclass(frozen=True)
class DataParallel:
  """How a data-parallel step spreads: `mesh` (1-D on AXIS) and `mode` (MODES).

  Hashable, so compiled steps can be cached per (config, DataParallel).
  """
  mesh: Mesh
  mode: str = "shard_map"

  def __post_init__(self):
    if self.mode not in MODES:
      raise UserError(f"parallel mode {self.mode!r}: must be one of {', '.join(MODES)}")
    if self.mode == "pmap" and jax.process_count() > 1:
      raise UserError("--parallel pmap runs within one process; several processes train "
                      "with --parallel shard_map")

  @property
  def size(self) -> int:
    """The number of devices (of every process) a step runs on."""
    return self.mesh.size

  @property
  def _devices(self) -> Sequence[jax.Device]:
    return list(self.mesh.devices.flat)

  def put_state(self, tree):
    """The state (or constants) on every device: replicated. One device: as it is (jit
    places it)."""
    if self.size == 1:
      return tree
    if self.mode == "pmap":
      return flax.jax_utils.replicate(tree, self._devices)
    return replicated(tree, self.mesh)

  def put_batch(self, batch):
    """A global batch (leading axis divisible by `size`, the same on every process), each
    device given its consecutive rows."""
    if self.size == 1:
      return batch
    if self.mode == "pmap":
      return jax.tree_util.tree_map(
          lambda x: x.reshape(self.size, x.shape[0] // self.size, *x.shape[1:]), batch)
    return split_rows(batch, self.mesh)

  def to_host(self, tree):
    """Numpy copies of a replicated state or step statistics (as put_state placed them)."""
    if self.size > 1 and self.mode == "pmap":
      return jax.tree_util.tree_map(lambda x: np.asarray(x[0]), tree)
    return jax.tree_util.tree_map(_local_copy, tree)

  def compile(self, step_fn: Callable, constants: Tuple[Any, ...] = ()) -> Callable:
    """`(state, batch) -> (state, stats)` of `step_fn(state, batch, *constants,
    axis_name=None | AXIS)`, the state donated. Takes and returns what put_state and
    put_batch make; `constants` (style vectors, a frozen encoder) are placed once, here."""
    placed = (jax.device_put(constants, self._devices[0]) if self.size == 1
              else self.put_state(constants))
    if self.size == 1:
      compiled = jax.jit(step_fn, donate_argnums=0)
    elif self.mode == "pmap":
      compiled = jax.pmap(functools.partial(step_fn, axis_name=AXIS), axis_name=AXIS,
                          donate_argnums=0)
    else:
      # check_vma=False: the step is pmap's per-device program, its own pmean averages the
      # gradients. (With the check, differentiating with respect to the replicated params
      # would already sum the gradients over the devices, and the pmean would not undo it.)
      replicated, split = PartitionSpec(), PartitionSpec(AXIS)
      compiled = jax.jit(jax.shard_map(
          functools.partial(step_fn, axis_name=AXIS), mesh=self.mesh,
          in_specs=(replicated, split) + (replicated,) * len(constants),
          out_specs=(replicated, replicated), check_vma=False), donate_argnums=0)
    return lambda state, batch: compiled(state, batch, *placed)


def data_parallel(n_devices: Optional[int] = None, mode: str = "shard_map") -> DataParallel:
  """DataParallel over data_mesh(n_devices)."""
  return DataParallel(data_mesh(n_devices), mode)
