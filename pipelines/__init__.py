"""Command lines and the dataset builder. Importing this package first checks that the installed
`factory` package is ours (`pipelines.install_check`: the name is also factory_boy's)."""

from pipelines import install_check as _install_check

_install_check.check()
