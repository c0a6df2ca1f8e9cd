"""A recording in one call from Python, as notebooks take it: ``daq.io.open`` -> pandas DataFrame (samples, and
events as their own table) and xarray Dataset, with units and the rig config as attributes."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io
import xarray as xr

import daq.io
from daq.errors import InputError
from daq.io.importer import import_file

N = 300
T = np.arange(N) / 100.0
F_OVER_MG = 0.4 + 0.1 * np.sin(2 * np.pi * T)
MAPS = ["x1=F_over_mg*0.05", "vb=5e-5"]


@pytest.fixture
def mat(tmp_path):
    path = tmp_path / "slider.mat"
    scipy.io.savemat(path, {"t": T, "F_over_mg": F_OVER_MG})
    return path


def test_open_a_run_file_to_pandas_with_units_rig_and_events(tmp_path, mat):
    run = import_file(mat, "belt-ndof", tmp_path / "run.h5", maps=MAPS)
    rec = daq.io.open(run)
    df = rec.to_pandas()
    assert df.index.name == "t" and np.allclose(df.index.to_numpy(), T)
    np.testing.assert_allclose(df["x1"].to_numpy(), F_OVER_MG * 0.05)
    assert df.attrs["units"]["x1"] == "m" and df.attrs["units"]["vb"] == "m/s"
    assert df.attrs["rig"] == "belt-ndof" and 'rig = "belt-ndof"' in df.attrs["rig_config"]
    events = rec.events_to_pandas()
    assert list(events["kind"]) == ["import"] and "slider.mat" in events["detail"][0]


def test_to_xarray_keeps_units_events_and_survives_netcdf(tmp_path, mat):
    rec = daq.io.open(mat, rig="belt-ndof", maps=MAPS)  # any importable file, through daq import's own path
    ds = rec.to_xarray()
    assert ds["x1"].attrs["units"] == "m" and ds["t"].attrs["units"] == "s"
    assert ds.sizes["t"] == N and ds.sizes["event"] == 1 and str(ds["event_kind"].values[0]) == "import"
    np.testing.assert_allclose(ds["F_over_mg"].values, F_OVER_MG)  # the file's other variables come along
    assert ds.attrs["rig"] == "belt-ndof"
    path = tmp_path / "rec.nc"
    ds.to_netcdf(path, engine="scipy")  # attributes are plain numbers and strings: a netCDF file takes them
    back = xr.open_dataset(path, engine="scipy")
    np.testing.assert_allclose(back["x1"].values, ds["x1"].values)
    assert back.attrs["rig_config"] == ds.attrs["rig_config"]
    back.close()


def test_open_needs_the_rig_for_a_foreign_file(mat):
    with pytest.raises(InputError) as info:
        daq.io.open(mat)
    assert str(mat) in str(info.value) and "rig" in str(info.value)
