"""What a run kind is: the one record the rest of the package asks about a kind of run
(`msnerf_jax.kinds.registry` holds one per kind)."""

import dataclasses
from typing import Any, Callable, Dict, Optional, Tuple

import numpy as np

from msnerf_jax.core.errors import UserError

# (camera: a view index, c2w [3, 4] or cameras.Camera; K style vectors [1024]) ->
# K images [K, H, W, 3] float32 in [0, 1].
StyleRenderer = Callable[[Any, Any], np.ndarray]


@dataclasses.dataclass(frozen=True)
class RunKind:
  """One kind of run: how its folder is read, what its params are and how it renders.

  Attributes:
    name: the kind as run.json saves it ("nerf", "adain", ...).
    config_class: its frozen config dataclass (run.json's "config").
    train_command: the command that makes a run of the kind (named in errors).
    title: how summaries name its renders ("multi-style", "feature-field").
    params_layout: the params tree every checkpoint of the kind holds, in words.
    init_params: (config, PRNG key) -> fresh params with that layout (shapes checked on
      load: `jax.eval_shape` of it), or None where the shapes are checked elsewhere.
    nerf_config: config -> the NerfConfig its views are sampled with (None: a kind with no
      scene, e.g. an AdaIN decoder).
    field: config -> the field the one renderer (msnerf_jax.nerf.render) draws with (None:
      the kind renders through another path).
    style_table: (run, scene) -> ({name: style vector [1024]} it renders by name, the
      (height, width) a style picture is cover-cropped to, or None) (None: no styles).
    style_renderer: (run, scene, chunk, grids, decoder) -> StyleRenderer of the run's views
      in K styles (None: a kind without styles). `decoder` is a loaded AdaIN decoder for the
      kinds that paint (paints_any_style), else None.
    paints_any_style: it paints any style picture at render time (needs a decoder), rather
      than the styles it was trained on.
    check_params: (params, config, record, where) -> None, UserError naming `where` for
      params that do not fit the run: for kinds whose shapes depend on the run folder as
      well as on the config (a painted run's style count), beside init_params' check.
  """
  name: str
  config_class: type
  train_command: str
  title: str
  params_layout: str
  init_params: Optional[Callable[[Any, Any], Any]] = None
  nerf_config: Optional[Callable[[Any], Any]] = None
  field: Optional[Callable[[Any], Any]] = None
  style_table: Optional[Callable[[Any, Any], Tuple[Dict[str, np.ndarray], Any]]] = None
  style_renderer: Optional[Callable[..., StyleRenderer]] = None
  paints_any_style: bool = False
  check_params: Optional[Callable[[Any, Any, Dict[str, Any], str], None]] = None


def check_param_shapes(params: Any, expected: Any, where: str) -> None:
  """UserError naming `where` unless params have the tree and shapes of `expected`."""
  import jax  # pylint: disable=g-import-not-at-top
  if expected is None:
    return
  if jax.tree_util.tree_structure(expected) != jax.tree_util.tree_structure(params):
    raise UserError(f"{where}: parameters of another architecture than its run.json says")
  for (path, want), got in zip(jax.tree_util.tree_leaves_with_path(expected),
                               jax.tree_util.tree_leaves(params)):
    if tuple(want.shape) != tuple(np.shape(got)):
      raise UserError(f"{where}: {jax.tree_util.keystr(path)} is {tuple(np.shape(got))}, "
                      f"its config expects {tuple(want.shape)} (another architecture)")
