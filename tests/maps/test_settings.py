"""The settings description (maps/settings.py): which registers a recipe holds and why the others
not, the write order the instruments need, scaling and range checks, and the ST initial value
printed and parsed back (ctest maps.settings). The generated types' staleness: settings.types."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, "maps"))
import mbmap  # noqa: E402
import settings  # noqa: E402


def names(dev):
    return [s.field for s in settings.fields(dev)]


def defaults(dev):
    return settings.from_raw(dev, {r.name: r.default for r in mbmap.load(dev).registers})


def test_write_order_scaling_then_limits_then_values_lock_last():
    mv = names("mvd94")
    assert mv[:5] == ["INPUT_TYPE", "UNIT", "DP", "LOLT", "HILT"] and mv[-1] == "LOCK"
    assert mv.index("HILT") < mv.index("SV")
    fdc = names("fdc100")
    assert fdc[:8] == ["INPT", "UNIT", "DP", "ALFN", "INLO", "INHI", "SP1L", "SP1H"]
    assert fdc.index("ALFN") < fdc.index("SP3") and fdc[-1] == "LOCK"
    assert names("mts9") == ["DECIMAL_SET"]


def test_left_out_with_a_reason():
    out = dict(settings.left_out("mvd94"))
    assert set(out) == {"FILT", "CH01", "CL01", "RTSH", "RTSL", "ADDR", "BAUD"}
    assert "confidence L" in out["FILT"] and "line" in out["BAUD"]
    fdc = dict(settings.left_out("fdc100"))
    assert "manual" in fdc["MV1"] and "CMND" in fdc["ADLO"] and "line" in fdc["PARI"]
    assert {"Real Data", "Author", "Type"} <= set(dict(settings.left_out("mts9")))
    for dev in mbmap.DEVICES:   # every writable register is either a field or left out
        m = mbmap.load(dev)
        fields = {s.reg.name for s in settings.fields(dev)}
        assert fields | set(dict(settings.left_out(dev))) == \
            {r.name for r in m.registers if "W" in r.access}
        assert not fields & set(dict(settings.left_out(dev)))


def test_types_real_for_scaled_and_codes_raw():
    f = settings.by_field("mvd94")
    assert f["SV"].st_type == "REAL" and f["PB"].st_type == "REAL"
    assert f["DP"].st_type == "UINT" and f["DP"].codes == (0x10, 0x11, 0x12, 0x13)
    assert f["TD"].st_type == "UINT" and f["TD"].raw_range == (0, 900)
    g = settings.by_field("fdc100")
    assert g["SP1"].st_type == "REAL" and g["SP1"].within == ("SP1L", "SP1H")
    assert g["INPT"].st_type == "UINT"


def test_to_raw_scales_with_the_recipes_own_dp_and_checks_ranges():
    v = defaults("mvd94")
    v.update(DP=0x11, SV=120.5, LOLT=-10.0, HILT=300.0, SPOF=-1.5)
    raw = settings.to_raw("mvd94", v)
    assert raw["SV"] == 1205 and raw["SPOF"] == -15 and raw["PB"] == 100
    with pytest.raises(settings.SettingError) as e:
        settings.to_raw("mvd94", {**v, "SV": 301.0})           # above the recipe's own HILT
    assert e.value.field == "SV" and "LOLT..HILT" in str(e.value)
    with pytest.raises(settings.SettingError) as e:
        settings.to_raw("mvd94", {**v, "A1SP": 100.1})         # raw 1001 > 1000
    assert e.value.field == "A1SP" and "-100..100" in str(e.value)
    with pytest.raises(settings.SettingError) as e:
        settings.to_raw("mvd94", {**v, "DP": 0x14})            # not a code of table DP
    assert e.value.field == "DP"
    with pytest.raises(settings.SettingError) as e:
        settings.to_raw("mvd94", {k: x for k, x in v.items() if k != "CT"})
    assert e.value.field == "CT" and "missing" in str(e.value)
    f = defaults("fdc100")
    f.update(SP1L=0.0, SP1H=400.0, SP1=150.0)
    assert settings.to_raw("fdc100", f)["SP1"] == 19999 + 1500


def test_st_initial_round_trip_alphabetical():
    for dev in mbmap.DEVICES:
        v = defaults(dev)
        text = settings.st_initial(dev, v)
        fields = [p.split(":=")[0].strip(" (\n") for p in text.split(",")]
        assert fields == sorted(fields) == sorted(v), text
        back = settings.parse_initial(dev, f"r : {settings.type_name(dev)} := {text};")
        assert settings.to_raw(dev, back) == settings.to_raw(dev, v)
    assert settings.parse_initial("mts9", "(* a comment *) (decimal_set := UINT#16#2)") == \
        {"DECIMAL_SET": 2}
    with pytest.raises(settings.SettingError) as e:
        settings.parse_initial("mts9", "(DECIMAL_SET := 2, BAUD := 3)")
    assert e.value.field == "BAUD"
    with pytest.raises(settings.SettingError):
        settings.parse_initial("mts9", "(DECIMAL_SET := 2.5)")   # UINT takes a whole number


def test_a_keyword_field_is_refused(tmp_path, monkeypatch):
    """A register whose map name is an ST keyword needs st_field (the MV-D94's TYPE has it)."""
    import json
    data = json.load(open(os.path.join(ROOT, "maps", "mts9.json"), encoding="utf-8"))
    for r in data["registers"]:
        if r["name"] == "Decimal Set":
            r["name"], r["aliases"] = "TYPE_X", []
            r["st_field"] = "END_TYPE"
    (tmp_path / "mts9.json").write_text(json.dumps(data))
    monkeypatch.setattr(mbmap, "HERE", str(tmp_path))
    mbmap._CACHE.clear()
    try:
        with pytest.raises(mbmap.MapError, match="no ST identifier"):
            settings.fields("mts9")
    finally:
        mbmap._CACHE.clear()


def test_generated_types_are_current():
    r = subprocess.run([sys.executable, os.path.join(ROOT, "maps", "settings.py"), "--check",
                        os.path.join(ROOT, "st_src", "MB_Settings.st")], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stdout + r.stderr
