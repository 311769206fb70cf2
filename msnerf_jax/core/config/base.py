"""What every config shares: the one-line refusals `validate()` raises, overrides, and the
JSON round trip (run.json) with the first difference between two saved configs."""

import dataclasses
import functools
from typing import Any, Dict, List, Optional, Tuple, Type, TypeVar

from msnerf_jax.core.errors import UserError

T = TypeVar("T")


def setting(default: Any, help: str) -> Any:  # pylint: disable=redefined-builtin
  """A config field with its help text: what `--help` says of its option (the command line is
  generated from the fields, msnerf_jax.cli.config_args) and what the docs say of it."""
  return dataclasses.field(default=default, metadata={"help": help})


def help_of(field: dataclasses.Field) -> str:
  """The help text of a config field (its name in words where it has none)."""
  return field.metadata.get("help", field.name.replace("_", " "))


def bad_setting(config: Any, name: str, problem: str, flag: Optional[str] = None) -> None:
  """Raises UserError `--NAME VALUE: problem` (the option that sets config.NAME; `flag`
  where the command line names it otherwise, e.g. --lr for lr_init)."""
  raise UserError(f"--{(flag or name).replace('_', '-')} {getattr(config, name)}: {problem}")


def check_at_least(config: Any, names, low: int = 1) -> None:
  """bad_setting for the first of `names` below `low` (an integer setting)."""
  for name in names:
    if getattr(config, name) < low:
      bad_setting(config, name, f"must be >= {low}")


def check_positive(config: Any, names, flag: Optional[str] = None) -> None:
  """bad_setting for the first of `names` that is not a finite number > 0."""
  for name in names:
    if not 0 < getattr(config, name) < float("inf"):
      bad_setting(config, name, "must be positive", flag)


def check_non_negative(config: Any, names) -> None:
  """bad_setting for the first of `names` that is not a finite number >= 0."""
  for name in names:
    if not 0.0 <= getattr(config, name) < float("inf"):
      bad_setting(config, name, "must be a number >= 0")


def check_hash_settings(config: Any) -> None:
  """UserError naming the first hash-grid setting (hash_levels, hash_features,
  hash_table_size, hash_min_res, hash_max_res) of a config that cannot work."""
  for name in ("hash_levels", "hash_features", "hash_min_res"):
    if getattr(config, name) < 1:
      bad_setting(config, name, "must be >= 1")
  t = config.hash_table_size
  if t < 2 or t & (t - 1):
    bad_setting(config, "hash_table_size", "must be a power of two (>= 2)")
  if config.hash_max_res < config.hash_min_res:
    bad_setting(config, "hash_max_res", f"finest resolution below the coarsest (--hash-min-res "
                                        f"{config.hash_min_res})")


def nested_class(field: dataclasses.Field) -> Optional[Type]:
  """The config class of a nested config field (a `nerf` or `optim`), None for a setting."""
  factory = field.default_factory
  if isinstance(factory, functools.partial):
    factory = factory.func
  return factory if isinstance(factory, type) and dataclasses.is_dataclass(factory) else None


def is_flat(field: dataclasses.Field) -> bool:
  """Whether a nested config's settings are its parent's own options and overrides (the
  `optim` block: --steps, not --optim-steps)."""
  return bool(field.metadata.get("flat"))


def flat_fields(cls: Type) -> List[Tuple[Optional[str], dataclasses.Field]]:
  """(the flat nested field holding it or None, field) of every setting of `cls` as its
  command line has them: its own settings, the flat nested configs' settings in their place;
  other nested configs (a run's `nerf`) left out."""
  found = []
  for field in dataclasses.fields(cls):
    if is_flat(field):
      found += [(field.name, f) for f in dataclasses.fields(nested_class(field))]
    elif nested_class(field) is None:
      found.append((None, field))
  return found


def setting_of(config: Any, name: str) -> Any:
  """A setting of `config` by its flat name (`steps` of a config with an `optim` block)."""
  for holder, field in flat_fields(type(config)):
    if field.name == name:
      return getattr(getattr(config, holder) if holder else config, name)
  return getattr(config, name)


def override(config: T, **overrides: Any) -> T:
  """`config` with the overrides that are not None, by flat name (a setting of its `optim`
  block as `steps=...`). On a NerfConfig, a net_depth given without skip_layer puts the skip
  connection after the middle layer."""
  overrides = {k: v for k, v in overrides.items() if v is not None}
  if "net_depth" in overrides and hasattr(config, "skip_layer"):
    overrides.setdefault("skip_layer", overrides["net_depth"] // 2)
  for holder in {h for h, _ in flat_fields(type(config)) if h}:
    mine = {f.name: overrides.pop(f.name)
            for f in dataclasses.fields(getattr(config, holder)) if f.name in overrides}
    if mine:
      overrides[holder] = dataclasses.replace(getattr(config, holder), **mine)
  return dataclasses.replace(config, **overrides)


def to_dict(config: Any) -> Dict[str, Any]:
  return dataclasses.asdict(config)


def _unflatten(cls: Type, values: Dict[str, Any]) -> Dict[str, Any]:
  """`values` with the keys of a flat nested config's settings moved into it, where it is
  missing: a run.json written before the `optim` block held its settings at the top. (Where
  the block is there, such keys stay, and are refused as unknown.)"""
  values = dict(values)
  own = {f.name for f in dataclasses.fields(cls)}
  for field in dataclasses.fields(cls):
    if is_flat(field) and field.name not in values:
      moved = {f.name: values.pop(f.name) for f in dataclasses.fields(nested_class(field))
               if f.name in values and f.name not in own}
      if moved:
        values[field.name] = moved
  return values


def from_dict(cls: Type[T], values: Dict[str, Any], source: str = "config",
              base: Optional[T] = None) -> T:
  """Builds `cls` from a dict, naming unknown or mistyped keys in a UserError; keys it lacks
  keep `base`'s values (default: the class's defaults; a nested config: its parent's)."""
  if not isinstance(values, dict):
    raise UserError(f"{source}: expected a JSON object, got {type(values).__name__}")
  fields = {f.name: f for f in dataclasses.fields(cls)}
  values = _unflatten(cls, values)
  unknown = sorted(set(values) - set(fields))
  if unknown:
    raise UserError(f"{source}: unknown {cls.__name__} keys {unknown}")
  clean = {}
  for name, value in values.items():
    nested = nested_class(fields[name])
    if nested is not None:
      clean[name] = from_dict(nested, value, f"{source}: {name}", fields[name].default_factory())
      continue
    default = fields[name].default
    if default is not dataclasses.MISSING and default is not None:
      kind = type(default)
      if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value) if abs(value) < 2 ** 1024 else value  # (10**400: not a float)
      if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise UserError(f"{source}: {name} should be {kind.__name__}, got {value!r}")
    clean[name] = value
  return dataclasses.replace(base, **clean) if base is not None else cls(**clean)


# Keys a difference is reported on first: what kind of model a run is.
NAMED_FIRST = ("trunk", "sampler")


def diff(saved: Dict[str, Any], current: Dict[str, Any], prefix: str = "") -> Optional[str]:
  """The first differing key between two nested dicts, as 'key: saved A, now B', or None
  (at each level, the NAMED_FIRST keys in their order, then the others alphabetically)."""
  rank = lambda k: (NAMED_FIRST.index(k) if k in NAMED_FIRST else len(NAMED_FIRST), k)
  for key in sorted(set(saved) | set(current), key=rank):
    a, b = saved.get(key, "<missing>"), current.get(key, "<missing>")
    if isinstance(a, dict) and isinstance(b, dict):
      found = diff(a, b, f"{prefix}{key}.")
      if found:
        return found
    elif a != b:
      return f"{prefix}{key}: saved {a!r}, now {b!r}"
  return None
