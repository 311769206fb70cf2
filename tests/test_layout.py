"""The package's import graph (read from the source with ast, nothing imported): no cycles but
the data-format registry, the library never imports its command line, and only the command
line and the pipeline import the trainers."""

import ast
import os

import msnerf_jax

PACKAGE = os.path.dirname(os.path.abspath(msnerf_jax.__file__))
# data.scene.load_scene imports the format loaders, which use the Scene they return.
ALLOWED_CYCLES = [{"msnerf_jax.data.scene", "msnerf_jax.data.blender", "msnerf_jax.data.llff",
                   "msnerf_jax.data.captures"}]


def modules():
  """Dotted module name -> file of every module of the package."""
  found = {}
  for root, _, files in os.walk(PACKAGE):
    for name in files:
      if name.endswith(".py"):
        path = os.path.join(root, name)
        rel = os.path.relpath(path, os.path.dirname(PACKAGE))[:-3].replace(os.sep, ".")
        found[rel[:-len(".__init__")] if rel.endswith(".__init__") else rel] = path
  return found


def import_graph():
  """Module -> the package modules it imports (at the top or inside functions)."""
  mods = modules()
  graph = {}
  for module, path in mods.items():
    deps = set()
    with open(path) as f:
      tree = ast.parse(f.read())
    for node in ast.walk(tree):
      if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
      elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
        names = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in mods else node.module
                 for a in node.names]
      else:
        continue
      deps.update(n for n in names if n in mods and n != module)
    graph[module] = deps
  return graph


def cycles(graph):
  """The strongly connected components of more than one module (Tarjan)."""
  index, low, stack, on_stack, found = {}, {}, [], set(), []

  def visit(v):
    index[v] = low[v] = len(index)
    stack.append(v)
    on_stack.add(v)
    for w in sorted(graph[v]):
      if w not in index:
        visit(w)
        low[v] = min(low[v], low[w])
      elif w in on_stack:
        low[v] = min(low[v], index[w])
    if low[v] == index[v]:
      component = set()
      while True:
        w = stack.pop()
        on_stack.discard(w)
        component.add(w)
        if w == v:
          break
      if len(component) > 1:
        found.append(component)

  for v in sorted(graph):
    if v not in index:
      visit(v)
  return found


def test_no_import_cycle_but_the_format_registry():
  assert [c for c in cycles(import_graph()) if c not in ALLOWED_CYCLES] == []


def test_the_library_never_imports_the_cli():
  cli = "msnerf_jax.cli"
  offenders = {m: sorted(d for d in deps if d == cli or d.startswith(cli + "."))
               for m, deps in import_graph().items()
               if not (m == cli or m.startswith(cli + ".") or m == "msnerf_jax.__main__")}
  assert {m: d for m, d in offenders.items() if d} == {}


def inside(module, package):
  return module == package or module.startswith(package + ".")


def test_only_the_cli_and_the_pipeline_import_the_trainers():
  train = "msnerf_jax.train"
  allowed = lambda m: (inside(m, "msnerf_jax.cli") or inside(m, train)
                       or m == "msnerf_jax.pipeline.stages"  # the stage table
                       or m == "msnerf_jax.api")  # the public surface: `ms.paint`
  offenders = {m: sorted(d for d in deps if inside(d, train))
               for m, deps in import_graph().items() if not allowed(m)}
  assert {m: d for m, d in offenders.items() if d} == {}


# The layers, bottom to top: a module may import its own layer and the layers below it.
LAYERS = ("core", "nerf", "models", "data", "style", "kinds", "eval", "train", "pipeline",
          "viewer", "cli")


def layer_of(module):
  """The index in LAYERS of a module of the package (None: the top-level package)."""
  parts = module.split(".")
  return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else None


def test_every_module_sits_in_a_layer():
  loose = [m for m in modules() if layer_of(m) is None
           and m not in ("msnerf_jax", "msnerf_jax.__main__", "msnerf_jax.api")]
  assert loose == []


def test_no_import_runs_upward():
  upward = {}
  for module, deps in import_graph().items():
    here = layer_of(module)
    if here is None:  # the top-level package and msnerf_jax.api: the public surface.
      continue
    above = sorted(d for d in deps if layer_of(d) is not None and layer_of(d) > here)
    if above:
      upward[module] = above
  assert upward == {}


def test_the_command_line_starts_without_jax():
  """`msnerf --help` and every error about options come before any heavy import: building the
  parser imports neither jax nor flax (each verb imports what it runs)."""
  import subprocess  # pylint: disable=g-import-not-at-top
  import sys  # pylint: disable=g-import-not-at-top
  code = ("import sys; from msnerf_jax import cli; cli.build_parser(); "
          "print(sorted(m for m in ('jax', 'flax', 'optax', 'orbax') if m in sys.modules))")
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                       cwd=os.path.dirname(PACKAGE))
  assert out.stdout.strip() == "[]"


# Sizes a reader can hold at once (issue 44's targets): a module's lines and a function's,
# from its `def` line to its last, docstring included.
MAX_MODULE_LINES = 350
MAX_FUNCTION_LINES = 60


def test_modules_and_functions_stay_short():
  long = []
  for module, path in sorted(modules().items()):
    with open(path) as f:
      source = f.read()
    if source.count("\n") > MAX_MODULE_LINES:
      long.append(f"{module}: {source.count(chr(10))} lines")
    for node in ast.walk(ast.parse(source)):
      if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
        lines = node.end_lineno - node.lineno + 1
        if lines > MAX_FUNCTION_LINES:
          long.append(f"{module}.{node.name}: {lines} lines")
  assert long == []
