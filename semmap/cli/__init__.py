"""The command line: parse arguments, drive progress bars, map errors to exit codes."""
