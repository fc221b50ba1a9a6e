import factory._startup  # noqa: F401  (first: Ctrl-C while a command starts is one line)
