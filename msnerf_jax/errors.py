"""The one exception type for problems a user can fix (bad files, bad flags)."""


class UserError(Exception):
  """A problem with the user's input, reported by the CLI as one line and exit code 2.

  The message should name the file or option and say what is wrong with it.
  """
