"""The operator's live web page (``daq daemon --web``): a bus subscriber in its own process, a page shipped here.

``server.py`` is the process (Starlette + uvicorn, WebSocket frames), ``feed.py`` its bus side and
per-page frames, ``history.py`` the decimation (min/max envelope per pixel column), ``messages.py``
every message crossing a boundary, ``process.py`` the daemon's side; ``static/`` the page (uPlot).

Decision record: docs/decisions/0020-live-web-page.md.

Exports (``__all__``) ``WebProcess``, ``WebCfg`` and ``StreamHistory``, each imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__, {"process": ["WebProcess"], "messages": ["WebCfg"], "history": ["StreamHistory"]}
)
