"""What moves over sockets: the ZeroMQ sample bus and the recorder process.

Exports (``__all__``) the bus's publisher and subscriber and the recorder, each imported when first used.
"""

from daq import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__, {"bus": ["Publisher", "Subscriber", "BusCfg"], "recorder": ["Recorder", "RecorderCfg"]}
)
