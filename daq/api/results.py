"""What the Python loop returns: the JSON the command line prints, as typed objects a notebook reads.

Why objects over the JSON and not a second schema: the command's JSON is the contract (files, archives and
scripts read it), so a result *is* that JSON (``.json``), every field of it an attribute (``cmp.by_regime``), and
the fields a reader uses first are typed properties with their meaning (docs/concepts.md defines each term).
``.figure()`` draws the figure the command's ``--report`` draws, with the same function, and returns it as a
``Figure``: the PNG's path, shown inline by Jupyter (``_repr_png_``).
"""

from __future__ import annotations

import copy
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any


class Figure:
    """A PNG the loop drew: ``.path``; Jupyter shows it inline, ``.data`` is its bytes."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    @property
    def data(self) -> bytes:
        return self.path.read_bytes()

    def _repr_png_(self) -> bytes:
        return self.data

    def __repr__(self) -> str:
        return f"Figure({str(self.path)!r})"


class Result:
    """The JSON of one step of the loop, its fields as attributes; ``.figure(path)`` draws its figure."""

    FIGURE = "figure.png"  # the file name the command's report gives the figure

    def __init__(self, json: dict[str, Any], draw: Callable[[Path], object] | None = None) -> None:
        self.json = json
        self._draw = draw

    def __getattr__(self, name: str) -> Any:
        # only reached for names the class does not define: the JSON's fields
        json = self.__dict__.get("json", {})
        if name in json:
            return json[name]
        raise AttributeError(f"{type(self).__name__} has no field {name!r} (fields: {', '.join(json)})")

    def __dir__(self) -> list[str]:
        return sorted(set(super().__dir__()) | set(self.json))

    def to_dict(self) -> dict[str, Any]:
        """A copy of the JSON, to change without changing the result."""
        return copy.deepcopy(self.json)

    def figure(self, path: str | Path | None = None) -> Figure:
        """Draw the figure the command's ``--report`` draws into ``path`` (default: a temporary file)."""
        if self._draw is None:
            raise ValueError(f"this {type(self).__name__} has no figure (nothing was fitted or proposed)")
        if path is None:
            path = Path(tempfile.mkdtemp(prefix="daq-figure-")) / self.FIGURE
        self._draw(Path(path))
        return Figure(path)

    def __repr__(self) -> str:
        return f"<{type(self).__name__}: {self}>"


class Comparison(Result):
    """`daq compare`: the model fitted to the recording, its error against the noise floor, and where it fails."""

    FIGURE = "compare.png"

    def __init__(self, json: dict[str, Any], draw: Callable[[Path], object] | None = None, text: str = "") -> None:
        super().__init__(json, draw)
        self.text = text  # what the command prints without --json

    @property
    def error(self) -> float:
        """rms of model - measured of the primary signal on the held-out windows, in ``error_unit``."""
        return float(self.json["error"])

    @property
    def noise_floor(self) -> float:
        """The error a perfect model would show on this record (its own fit on a noisy copy of itself)."""
        return float(self.json["noise_floor"])

    @property
    def error_unit(self) -> str:
        return str(self.json["error_unit"])

    @property
    def excess(self) -> float:
        """``error - noise_floor``: what a better model could still remove."""
        return self.error - self.noise_floor

    @property
    def parameters(self) -> dict[str, dict[str, float | None]]:
        """Each free parameter's fitted ``value`` and ``std``."""
        return self.json["parameters"]

    def __str__(self) -> str:
        return f"error {self.error:.4g} {self.error_unit} (noise floor {self.noise_floor:.4g}), {self.json['model']}"


class Diagnosis(Result):
    """`daq diagnose`: which effect of the catalog the model lacks, how firmly, and what adding it delivers."""

    FIGURE = "diagnose.png"

    def __init__(self, json: dict[str, Any], draw: Callable[[Path], object] | None = None, text: str = "") -> None:
        super().__init__(json, draw)
        self.text = text

    @property
    def missing_effect_found(self) -> bool:
        return bool(self.json["missing_effect_found"])

    @property
    def named(self) -> list[str]:
        """The effects named: each beats its rivals by a margin whose 5 % bound is above zero."""
        return list(self.json["named"])

    @property
    def undecided(self) -> list:
        """Ties the record cannot settle (``daq propose`` finds the run that does)."""
        return list(self.json["undecided"])

    @property
    def summary(self) -> str:
        """The sentence the command prints first."""
        return str(self.json["summary"])

    @property
    def final_reduction(self) -> float | None:
        """Share of the excess that `daq model add` + `daq compare` remove with the effects named."""
        v = self.json.get("final_reduction")
        return None if v is None else float(v)

    def add_commands(self) -> list[str]:
        """The `daq model add MODEL ...` arguments of each step added (``accel-sign --form relative``)."""
        return [step["effect"] + (f" --form {step['form']}" if step.get("form") else "")
                for step in self.json.get("sequence", [])] if self.missing_effect_found else []

    def __str__(self) -> str:
        return self.summary


class Proposal(Result):
    """`daq propose`: the drive programme under which the rival explanations of a record differ most."""

    FIGURE = "next.png"

    def __init__(self, json: dict[str, Any], draw: Callable[[Path], object] | None = None, text: str = "") -> None:
        super().__init__(json, draw)
        self.text = text  # what the command prints without --json

    @property
    def programme(self) -> str | None:
        """The proposed run's name (None: nothing left to decide)."""
        return self.json.get("programme")

    @property
    def decides(self) -> bool | None:
        """Whether the proposed run separates every pair of rivals (z of its worst pair >= 2.33)."""
        return self.json.get("decides")

    @property
    def z(self) -> float | None:
        return self.json.get("z")

    @property
    def separation(self) -> float | None:
        return self.json.get("separation")

    @property
    def ramp(self) -> str | None:
        """The ramp file's text (TOML) that `daq ctl ramp` runs."""
        return self.json.get("ramp")

    def __str__(self) -> str:
        if self.programme is None:
            return f"no run to propose: {self.json.get('reason', '')}"
        return f"next run: {self.programme} ({'decides' if self.decides else 'does not decide'}, z {self.z:.2f})"
