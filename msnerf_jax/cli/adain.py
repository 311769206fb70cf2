"""`msnerf adain ...` (placeholder until the AdaIN stage lands)."""


def register(commands, formatter):
  del commands, formatter
