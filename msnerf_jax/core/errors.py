"""The one exception type for problems a user can fix (bad files, bad flags)."""


class UserError(Exception):
  """A problem with the user's input, reported by the CLI as one line and exit code 2.

  The message should name the file or option and say what is wrong with it.
  """


class Interrupted(Exception):
  """Training stopped by a signal (SIGTERM, Ctrl-C); the CLI prints it as one line and
  exits with 128 + the signal number.

  Attributes: signum, step (the last step done) and checkpoint (the step of the latest
  checkpoint: `step` when one was saved on the way out).
  """

  def __init__(self, signum: int, step: int, checkpoint: int):
    import signal  # pylint: disable=g-import-not-at-top
    self.signum, self.step, self.checkpoint = signum, step, checkpoint
    kept = ("checkpoint saved" if checkpoint == step else
            f"the checkpoint of step {checkpoint}, saved less than a minute ago, is kept")
    super().__init__(f"stopped by {signal.Signals(signum).name} at step {step} ({kept}); "
                     "re-run the same command to resume")
