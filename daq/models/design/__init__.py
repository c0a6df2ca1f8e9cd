"""The design of experiments: the next run under which the rival explanations of a record differ most.

``programmes`` holds the drive programmes a rig can run (the family a proposal searches); ``proposal`` fits the
rivals a diagnosis leaves standing, predicts each programme's record under each and scores how well it would tell
them apart. Decision record: docs/decisions/0036-propose-the-deciding-run.md.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {"proposal": ["Proposal", "Rival"], "programmes": ["family"]})
