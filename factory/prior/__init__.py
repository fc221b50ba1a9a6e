"""Usage priors: part, colour and connection-kind weights fitted to real designs, and the part set
they give the sampler on a library.

`fit_prior(designs, reader)` fits one; `load_prior(path)` reads one (default: the shipped
`DEFAULT_PRIOR`); `choose_parts(prior, reader)` says which of its parts a library holds and the
factory can connect, with the reason for every part left out.
"""

from factory.prior.families import family, unprinted
from factory.prior.fit import DEFAULT_TEMPER, fit_prior
from factory.prior.prior import (
    CONNECTION_KINDS,
    DEFAULT_PRIOR,
    DesignSource,
    PartUse,
    Prior,
    PriorError,
    load_prior,
)

__all__ = [
    "CONNECTION_KINDS",
    "DEFAULT_PRIOR",
    "DEFAULT_TEMPER",
    "DesignSource",
    "PartUse",
    "Prior",
    "PriorError",
    "family",
    "fit_prior",
    "load_prior",
    "unprinted",
]
