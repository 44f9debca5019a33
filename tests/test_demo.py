"""`camcal demo` recovers its synthetic camera within the stated tolerances."""

from camcal.cli import main
from camcal.demo import run_demo
from camcal.rig import Rig


def test_demo_recovers_truth(tmp_path):
    report = run_demo(tmp_path, seed=0)
    assert all(row.ok for row in report.rows), report.table()
    assert {row.quantity for row in report.rows} >= {"fx", "fy", "camera centre"}
    rig = Rig.load(tmp_path / "dlt.rig.json")
    fx = next(row for row in report.rows if row.quantity == "fx")
    assert rig.cameras[0].K[0, 0] == fx.recovered


def test_demo_command(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert "recovered" in out and "dlt.rig.json" in out
