"""The seed papers' own analyses (one package each: paper000, paper001, paper002) and the drum campaign.

Exports its five analyses (``__all__``) as subpackages, each imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, modules=["campaign", "paper000", "paper001", "paper002", "rsf"])
