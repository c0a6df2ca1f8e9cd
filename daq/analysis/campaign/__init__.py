"""``daq campaign drum``: paper 002's grid of thrusts x drum speeds, run through the daemon, resumable.

Why a package of its own: a campaign is hours of unattended rig time, so it is state, not a loop.
Each cell (thrust P, drum speed v0) is one scripted ramp recorded by the daemon into its own file,
then analysed by ``daq analyse drum-mu``; after each cell the state is rewritten atomically, so a
kill at any instant leaves either the old or the new state, and rerunning (or ``--resume``) skips
finished cells and redoes an interrupted one. Method and measurements: docs/campaign.md.

- ``state.py``: the campaign's settings, cells and results (pydantic), the state file (atomic
  save, load with one-line errors), each cell's programme and each thrust row's rig config.
- ``supervision.py``: the per-row ``daq daemon --sim`` (``DaemonRow``), process liveness, ending
  what a killed campaign left (``end_stale``).
- ``run.py``: the run loop (``Campaign``: rows, cells, record, analyse, ETA; ``Interrupted``).
- ``table.py``: table.csv / table.json and the grid figure coefficients.png.

The command line (options, defaults of the grid, resume checks, operator prompts) is
``daq/cli/campaign.py``.

Exports (``__all__``) the run loop, the state file's functions and ``write_table``, each imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "run": ["Campaign", "Interrupted"],
        "state": ["CampaignCfg", "load_state", "new_state", "save_state"],
        "table": ["write_table"],
    },
)
