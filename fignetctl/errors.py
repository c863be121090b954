"""The one exception type the library raises for problems a user can fix.

Commands never catch it themselves: `fignetctl.cli` turns it into a one-line
click error, so bad input never ends in a traceback.
"""


class FignetError(Exception):
    """A problem with the user's input or environment, described in one sentence."""


class SettingError(FignetError):
    """A setting (on the command line, an option) whose value the command cannot use; the CLI
    reports it as a usage error (exit code 2), as for a value click itself refuses."""


class FormatError(FignetError):
    """A file that does not follow its documented format."""
