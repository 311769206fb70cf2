"""Any run's views in K styles, whatever its kind: its style table and renderer from the
registry, with the AdaIN decoder loaded for the kinds that paint at render time."""

from typing import Any, Dict, Optional, Tuple

import numpy as np

from msnerf_jax.core.errors import UserError
from msnerf_jax.kinds.base import StyleRenderer
from msnerf_jax.kinds.registry import get_kind
from msnerf_jax.kinds.stylized_scenes import load_decoder


def style_rendering(run, scene, chunk: Optional[int] = None, grids: Optional[int] = None,
                    decoder_dir: Optional[str] = None
                    ) -> Tuple[Dict[str, np.ndarray], Any, StyleRenderer]:
  """(style table {name: vector [1024]}, the (height, width) style pictures are
  cover-cropped to or None, renderer of one camera in K styles) of a loaded run.

  decoder_dir: the AdaIN run that paints a kind which paints any style (default: the one it
  was trained with). UserError for a kind without styles.
  """
  kind = get_kind(run.kind)
  if kind.style_renderer is None:
    raise UserError(f"{run.run_dir}: a {run.kind!r} run has no styles")
  table, size = kind.style_table(run, scene)
  return table, size, kind.style_renderer(run, scene, chunk, grids,
                                          painting_decoder(run, decoder_dir))


def painting_decoder(run, decoder_dir: Optional[str] = None):
  """The loaded AdaIN decoder that paints a run of a kind which paints any style at render
  time (`decoder_dir`, default the one it was trained with); None for the other kinds."""
  if not get_kind(run.kind).paints_any_style:
    return None
  return load_decoder(decoder_dir or run.record["decoder"])
