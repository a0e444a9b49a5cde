"""Built-in monitoring plugins of fault_screen, registered through entry points like a third
party's (see ``[project.entry-points."fault_screen.alerts"]`` and ``"fault_screen.sources"`` in
the project's pyproject.toml):

* alerts: ``jsonl`` (JSON-lines file), ``webhook`` (signed HTTP POST), ``command`` (a program);
* sources: ``csv`` (follow a growing CSV log by polling), ``stdin`` (the log on standard input).
"""
