"""A sampler configuration whose parts and colours come from a usage prior and a library
(`configure`), and the line that says what the library could not give."""

from __future__ import annotations

import os
from collections import defaultdict
from dataclasses import replace

from factory.ldraw import Reader
from factory.prior.choose import PartChoice, choose_parts, embedded_choice
from factory.prior.prior import DEFAULT_PRIOR, Prior, load_prior
from factory.sampler.config import SamplerConfig, SamplerConfigError


def is_embedded(reader: Reader) -> bool:
    return type(reader.library.source).__name__ == "MemorySource"


def configure(config: SamplerConfig, reader: Reader, prior: str | os.PathLike | None = None, *,
              parts: bool = True, colours: bool = True, progress=None,
              loaded: Prior | None = None) -> tuple[SamplerConfig, PartChoice | None]:
    """`config` with its parts (if `parts`) and colours (if `colours`) drawn from the prior in
    `prior` (default: the shipped one; `loaded`: that file already read) on `reader`'s library,
    and the choice made (None where nothing was drawn from a library: both given, or the
    embedded library, whose choice needs no reading). A prior none of whose parts the library
    can use is a `SamplerConfigError`."""
    if not parts and not colours:
        return replace(config, prior=""), None
    loaded = loaded if loaded is not None else load_prior(prior)
    label = loaded.label(prior)
    if is_embedded(reader):
        p, c = embedded_choice(loaded)
        if not p and parts:
            raise SamplerConfigError(f"prior {label}: none of its parts is in the embedded library; give --parts")
        return replace(config, parts=p if parts else config.parts, colours=c if colours else config.colours,
                       prior=label), None
    choice = choose_parts(loaded, reader, progress)
    if parts and not choice.parts:
        raise SamplerConfigError(f"prior {label}: none of its {len(loaded.parts)} parts is usable in the "
                                 f"{reader.library.description}; give --parts")
    if colours and not choice.colours:
        raise SamplerConfigError(f"prior {label}: none of its colours is in the {reader.library.description}'s "
                                 "LDConfig.ldr; give --colours")
    return replace(config, parts=choice.parts if parts else config.parts,
                   colours=choice.colours if colours else config.colours, prior=label), choice


def report(choice: PartChoice, config: SamplerConfig, library: str) -> str:
    """One line: how much of the prior the library gives, and what was left out and why."""
    why: dict[str, list] = defaultdict(list)
    for left in choice.left_out:
        why[left.reason if not left.reason.startswith("cannot be read") else "cannot be read"].append(left)
    parts = "; ".join(f"{len(v)} {k} ({sum(x.weight for x in v):.1%})"
                      for k, v in sorted(why.items(), key=lambda kv: -sum(x.weight for x in kv[1])))
    return (f"prior {config.prior}: {len(choice.parts)} parts of the {library} drawn, {choice.used_weight:.1%} of "
            f"the prior's usage; left out: {parts or 'none'} (`python -m pipelines.parts` lists them)")


__all__ = ["DEFAULT_PRIOR", "configure", "report"]
