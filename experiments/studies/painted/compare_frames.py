"""Paintings of one scene side by side: the painted rows of several `evaluate_painted.py`
outputs (their frames.png: rows style x (painted, per-frame AdaIN), 4 frames each), style
by style, with the first output's per-frame AdaIN row last; rows named on the left.

  python experiments/studies/painted/compare_frames.py --styles 4 \\
      --evals "before" DIR_A "this version" DIR_B --out figure.jpg
"""

import argparse

import numpy as np

from msnerf_jax.data import images as images_lib
from msnerf_jax.data import video


def split_frames(path: str, rows: int, columns: int = 4, pad: int = 2):
  """The frames of a write_grid image of `rows` x `columns` equal frames set `pad` apart:
  [rows][columns] of [h, w, 3]."""
  grid = images_lib.read_image(path)
  h = (grid.shape[0] - pad * (rows - 1)) // rows
  w = (grid.shape[1] - pad * (columns - 1)) // columns
  return [[grid[r * (h + pad):r * (h + pad) + h, c * (w + pad):c * (w + pad) + w]
           for c in range(columns)] for r in range(rows)]


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--evals", nargs="+", required=True,
                      help="LABEL DIR pairs: evaluate_painted.py output folders")
  parser.add_argument("--styles", type=int, required=True, help="styles in each frames.png")
  parser.add_argument("--names", nargs="*", default=None, help="the styles' names")
  parser.add_argument("--out", required=True)
  args = parser.parse_args(argv)
  pairs = list(zip(args.evals[::2], args.evals[1::2]))
  frames = {label: split_frames(f"{folder}/frames.png", 2 * args.styles)
            for label, folder in pairs}
  names = args.names or [f"style {i + 1}" for i in range(args.styles)]
  rows, labels = [], []
  for s, name in enumerate(names):
    for label, _ in pairs:
      rows.append([frames[label][2 * s]])
      labels.append(f"{name}: {label}")
    rows.append([frames[pairs[0][0]][2 * s + 1]])
    labels.append(f"{name}: per-frame AdaIN")
  figure = video.labelled_grid(rows, labels, [""])
  images_lib.write_image(args.out, np.clip(figure, 0.0, 1.0))
  print(args.out)


if __name__ == "__main__":
  main()
