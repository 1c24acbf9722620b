"""phyir.estimators: the registries of lighting methods and geometry networks, and a dummy of each,
registered here, offered by the commands and used by predict (docs/architecture.md, "How to add a
lighting method / a geometry network")."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from support.tiny_scenes import tiny_scene

import phyir
from phyir import inference as I
from phyir.cli import build_parser
from phyir.cli import main as cli
from phyir.errors import PhyIRError
from phyir.estimators import (
    DEFAULT_GEOMETRY,
    DEFAULT_LIGHTING,
    GeometryNetwork,
    LightingMethod,
    Registry,
    geometry_networks,
    lighting_methods,
    register_geometry,
    register_lighting,
)
from phyir.nets import ModelConfig, PhyIRModel

pytestmark = pytest.mark.usefixtures("one_thread")
NET = (64, 128)
DUMMY_LIGHT = 0.25  # the dummy method's probes: this everywhere
DUMMY_METALLIC = 0.125  # the dummy network's metalness: this everywhere


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return PhyIRModel(ModelConfig.named("lite", probe_size=(8, 16))).eval()


@pytest.fixture(scope="module")
def image():
    return tiny_scene(7, H=128, W=256).image


@pytest.fixture
def dummy_lighting():
    """A lighting method with constant probes, registered for one test."""
    method = register_lighting("dummy", "constant probes (a test's)",
                               lambda lnet, projected: torch.full_like(lnet, DUMMY_LIGHT), projects=False)
    yield method
    lighting_methods().unregister("dummy")


@pytest.fixture
def dummy_geometry():
    """A geometry network: GMNet's layers with a constant metalness, counting its loads and calls."""
    calls = {"load": 0, "run": 0}

    def load(model, device):
        calls["load"] += 1

        def run(xn):
            calls["run"] += 1
            out = dict(model.gmnet(xn))
            out["metallic"] = torch.full_like(out["metallic"], DUMMY_METALLIC)
            return out
        return run

    register_geometry("dummy_geo", "GMNet with constant metalness (a test's)", load)
    yield calls
    geometry_networks().unregister("dummy_geo")


def option(parser: argparse.ArgumentParser, command: str, flag: str) -> argparse.Action:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return next(a for a in sub.choices[command]._actions if flag in a.option_strings)


def test_the_built_in_estimators():
    assert sorted(lighting_methods().names()) == ["fused", "lnet", "projection"]
    assert geometry_networks().names() == ("gmnet",)
    assert DEFAULT_LIGHTING in lighting_methods() and DEFAULT_GEOMETRY in geometry_networks()
    assert I.DEFAULT_LIGHTING == DEFAULT_LIGHTING == "fused" and I.DEFAULT_GEOMETRY == "gmnet"
    projects = {name: m.projects for name, m in lighting_methods().items()}
    assert projects == {"fused": True, "lnet": False, "projection": True}
    for _, entry in [*lighting_methods().items(), *geometry_networks().items()]:
        assert entry.summary and "\n" not in entry.summary and len(entry.summary) < 100


def test_a_registered_dummy_is_offered_by_the_commands(dummy_lighting, dummy_geometry):
    parser = build_parser()
    lighting = option(parser, "predict", "--lighting")
    assert set(lighting.choices) == {"fused", "lnet", "projection", "dummy"}
    assert "dummy: constant probes (a test's)" in lighting.help
    assert "fused: " in lighting.help and "(default)" in lighting.help
    geometry = option(parser, "predict", "--geometry")
    assert set(geometry.choices) == {"gmnet", "dummy_geo"} and "dummy_geo: GMNet with" in geometry.help
    assert "dummy" in option(parser, "eval", "--lighting").choices


def test_a_registered_dummy_is_used_by_predict(model, image, dummy_lighting, dummy_geometry):
    sc = phyir.predict(image, model=model, net_size=NET, lighting="dummy", geometry="dummy_geo")
    assert sc.probes.shape == (4, 8, 3, 8, 16) and bool((sc.probes == DUMMY_LIGHT).all())
    assert sc.meta["predict.lighting"] == "dummy" and sc.meta["predict.geometry"] == "dummy_geo"
    assert dummy_geometry["load"] == 1 and dummy_geometry["run"] >= 1
    torch.testing.assert_close(sc.metallic, torch.full_like(sc.metallic, DUMMY_METALLIC))
    pts = torch.tensor([[1.0, -1.2, -2.0], [-2.0, 0.5, 0.4]])
    at = phyir.predict(image, model=model, net_size=NET, lighting="dummy", probes="points", points=pts)
    assert at.probes.shape == (2, 1, 3, 8, 16) and bool((at.probes == DUMMY_LIGHT).all())
    # the default network: GMNet's metalness, not the dummy's; no predict.geometry in the header
    plain = phyir.predict(image, model=model, net_size=NET, lighting="lnet")
    assert not torch.allclose(plain.metallic, sc.metallic) and "predict.geometry" not in plain.meta


def test_a_method_that_does_not_project_cannot_read_the_projection(model, image):
    register_lighting("peeks", "reads the projection without saying so", lambda lnet, projected: projected(),
                      projects=False)
    try:
        with pytest.raises(PhyIRError, match="'peeks' reads the projected probes"):
            phyir.predict(image, model=model, net_size=NET, lighting="peeks")
    finally:
        lighting_methods().unregister("peeks")


def test_unknown_names_are_one_line_listing_the_choices(model, image, capsys):
    with pytest.raises(PhyIRError) as e:
        phyir.predict(image, model=model, lighting="lnett")
    assert str(e.value) == "unknown lighting method 'lnett' (choose from fused, lnet, projection)"
    with pytest.raises(PhyIRError) as e:
        phyir.predict(image, model=model, geometry="effnet")
    assert str(e.value) == "unknown geometry network 'effnet' (choose from gmnet)"
    assert cli(["predict", "x.hdr", "-o", "y.exr", "--lighting", "lnett"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "invalid choice: 'lnett'" in err  # (argparse quotes the choices or not)
    assert all(name in err.split("choose from")[1] for name in ("fused", "lnet", "projection"))


def test_registering_a_name_twice():
    reg: Registry[LightingMethod] = Registry("lighting method", "phyir.test_no_such_group")

    def estimate(lnet, projected):
        return lnet

    a = reg.register(LightingMethod("a", "one", False, estimate))
    assert reg.register(LightingMethod("a", "one", False, estimate)) == a  # the same again: fine
    with pytest.raises(PhyIRError, match="'a' is already registered"):
        reg.register(LightingMethod("a", "another", False, estimate))
    assert reg.names() == ("a",) and reg.get("a") is a
    reg.unregister("a")
    with pytest.raises(PhyIRError, match=r"unknown lighting method 'a' \(choose from none"):
        reg.get("a")
    geo: Registry[GeometryNetwork] = Registry("geometry network", "phyir.test_no_such_group")
    net = geo.register(GeometryNetwork("g", "a network", lambda model, device: model.gmnet))
    assert list(geo) == [net]


NO_TORCH = """
import sys
from phyir.cli import main
for argv in (["--help"], ["predict", "--help"], ["eval", "--help"]):
    try:
        main(argv)
    except SystemExit:
        pass
from phyir.estimators import geometry_networks, lighting_methods
assert len(lighting_methods().names()) >= 3 and len(geometry_networks().names()) >= 1
assert "phyir.lighting.methods.fused" in sys.modules and "phyir.geometry_networks.gmnet" in sys.modules
bad = [m for m in ("torch", "numpy") if m in sys.modules]
assert not bad, bad
print("ok")
"""


def test_the_help_and_the_registries_do_not_import_torch():
    out = subprocess.run([sys.executable, "-c", NO_TORCH], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr[-2000:]


def test_the_docs_table_is_the_registries():
    """docs/architecture.md's table of estimators: every registered one, its summary and module."""
    text = (Path(__file__).resolve().parents[2] / "docs" / "architecture.md").read_text()
    rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in text.splitlines()
            if line.startswith(("| lighting |", "| geometry |"))]
    documented = {(kind, name.split()[0].strip("`"), summary, module.strip("`"))
                  for kind, name, summary, module in rows}
    registered = {(kind, name, entry.summary, (fn.__module__.replace(".", "/") + ".py"))
                  for kind, reg, attr in (("lighting", lighting_methods(), "estimate"),
                                          ("geometry", geometry_networks(), "load"))
                  for name, entry in reg.items() for fn in [getattr(entry, attr)]}
    assert documented == registered
    defaults = {r[1].split()[0].strip("`") for r in rows if "(default)" in r[1]}
    assert defaults == {DEFAULT_LIGHTING, DEFAULT_GEOMETRY}
