"""Path-traced datasets (issue 12, item 4): ``tof-mpd sim dataset --renderer pathtrace``.

Without mitsuba: the material -> Mitsuba BSDF/medium mapping by hand, the default scene draw
pinned to what it was before the "pathtrace" material set existed, the CLI's one-line error when
the extra is missing (simulated), the cell's checks. With the ``[pathtrace]`` extra: a tiny
path-traced dataset that loads back and is reproducible, and the physics of the cell's
path-traced captures (agreement with the built-in renderer on a diffuse box, metal, translucent
plastic and wax).
"""

from __future__ import annotations

import importlib.util
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from sim_helpers import small_camera

from tof_mpd_ros.camera import Intrinsics
from tof_mpd_ros.cli.main import main
from tof_mpd_ros.errors import InputError, SimulationError
from tof_mpd_ros.pose import look_at, pose_m_to_mm
from tof_mpd_ros.recordings import RecordingReader
from tof_mpd_ros.sim.cell import CameraModel, SimCell
from tof_mpd_ros.sim.dataset import (
    DatasetSpec,
    capture_scene,
    generate_dataset,
    pathtrace_seed,
    renderer_summary,
    scene_rng,
)
from tof_mpd_ros.sim.objects import (
    MATERIAL_ALUMINIUM,
    MATERIAL_DIFFUSE,
    MATERIAL_GLOSSY_PLASTIC,
    MATERIAL_NAMES,
    MATERIAL_STEEL,
    MATERIAL_TRANSLUCENT_PLASTIC,
    MATERIAL_WAX,
    METAL_IOR,
    normal_reflectance,
    object_library,
)
from tof_mpd_ros.sim.pathtrace import interior_mask
from tof_mpd_ros.sim.pathtrace import render as pathtrace_render
from tof_mpd_ros.sim.pathtrace.materials import (
    diffuse_reflectance,
    interior_medium,
    single_scattering_albedo,
    surface_bsdf,
)
from tof_mpd_ros.sim.raycast import render_surface
from tof_mpd_ros.sim.scene import PlacedObject, Scene, make_box_scene, make_scene
from tof_mpd_ros.sim.tof import ToFConfig

HAS_PATHTRACE = all(importlib.util.find_spec(m) is not None for m in ("mitsuba", "mitransient"))
needs_pathtrace = pytest.mark.skipif(not HAS_PATHTRACE,
                                     reason="the [pathtrace] extra (mitsuba) is not installed")

# --- without mitsuba -----------------------------------------------------------------------


def test_diffuse_and_glossy_keep_their_albedo_glossy_has_a_specular_coat() -> None:
    assert surface_bsdf(MATERIAL_DIFFUSE, 0.3) == {
        "type": "diffuse", "reflectance": {"type": "uniform", "value": 0.3}}
    glossy = surface_bsdf(MATERIAL_GLOSSY_PLASTIC, 0.7)
    assert glossy["type"] == "roughplastic"  # a rough dielectric coat over a diffuse base
    assert glossy["diffuse_reflectance"]["value"] == 0.7
    assert glossy["int_ior"] > 1.3 and 0.0 < glossy["alpha"] <= 0.3  # a visible specular lobe
    for material in (MATERIAL_DIFFUSE, MATERIAL_GLOSSY_PLASTIC):
        assert interior_medium(material, 0.5) is None
    json.dumps(glossy)  # plain values only


@pytest.mark.parametrize(("material", "reflectance"),
                         [(MATERIAL_ALUMINIUM, 0.8695), (MATERIAL_STEEL, 0.5556)])
def test_metals_are_rough_conductors(material: int, reflectance: float) -> None:
    bsdf = surface_bsdf(material, 0.2)  # the albedo does not enter: the index fixes it
    assert bsdf["type"] == "roughconductor" and bsdf["distribution"] == "ggx"
    assert (bsdf["eta"], bsdf["k"]) == METAL_IOR[material] and 0.0 < bsdf["alpha"] < 0.5
    # ((n - 1)^2 + k^2) / ((n + 1)^2 + k^2) by hand
    assert normal_reflectance(*METAL_IOR[material]) == pytest.approx(reflectance, abs=1e-4)
    assert interior_medium(material, 0.2) is None


@pytest.mark.parametrize("material", [MATERIAL_TRANSLUCENT_PLASTIC, MATERIAL_WAX])
def test_translucent_materials_are_media_that_reflect_their_albedo(material: int) -> None:
    assert surface_bsdf(material, 0.6) == {"type": "null"}  # index-matched boundary
    medium = interior_medium(material, 0.6)
    assert medium["type"] == "homogeneous" and medium["phase"] == {"type": "isotropic"}
    assert 0.1 < medium["sigma_t"] < 2.0  # per mm: a mean free path of about a millimetre
    assert diffuse_reflectance(medium["albedo"]) == pytest.approx(0.6, abs=1e-9)


def test_diffusion_reflectance_by_hand() -> None:
    # s = sqrt(3 (1 - 0.99)) = 0.1732: 0.99/2 (1 + e^{-4/3 s}) e^{-s} = 0.495 * 1.7938 * 0.8410
    assert diffuse_reflectance(0.99) == pytest.approx(0.7467, abs=2e-4)
    assert diffuse_reflectance(0.0) == 0.0 and diffuse_reflectance(1.0) == 1.0
    assert single_scattering_albedo(0.7467) == pytest.approx(0.99, abs=1e-4)
    assert single_scattering_albedo(0.9) > 0.998  # bright translucent objects: long walks


def test_unknown_material_or_albedo_is_refused() -> None:
    with pytest.raises(InputError, match="material_id"):
        surface_bsdf(17, 0.5)
    with pytest.raises(InputError, match="albedo"):
        interior_medium(MATERIAL_WAX, 1.5)
    with pytest.raises(InputError, match="materials"):
        object_library("mirror")


#: make_scene("train"/"test", default_rng([0, split, 0])) before the "pathtrace" material set
#: existed: (library id, material id, x mm, y mm, yaw rad), and the table albedo
PINNED_SCENES = {
    ("train", 1): (0.6779477582556268, [(34, 0, 316.804908, 112.964986, -2.896751),
                                        (2, 0, 373.056889, -70.925405, -0.515939),
                                        (43, 0, 525.507114, -36.124495, 2.385525),
                                        (57, 0, 553.121723, 105.502707, -1.207783),
                                        (45, 0, 401.128014, 138.151709, -1.210016)]),
    ("test", 2): (0.5161648078346375, [(24, 1, 474.218386, 52.946511, -1.550663),
                                       (21, 0, 357.471951, -114.614953, 3.11297),
                                       (28, 0, 302.868122, 115.80631, -0.082147)]),
}


def _rows(scene: Scene) -> list[tuple[int, int, float, float, float]]:
    return [(o.spec.library_id, o.spec.material_id, round(o.x_mm, 6), round(o.y_mm, 6),
             round(o.yaw_rad, 6)) for o in scene.objects]


@pytest.mark.parametrize(("split", "split_id"), [("train", 1), ("test", 2)])
def test_default_scene_draw_is_unchanged(split: str, split_id: int) -> None:
    table_albedo, rows = PINNED_SCENES[(split, split_id)]
    scene = make_scene(split, np.random.default_rng([0, split_id, 0]))
    assert scene.table.albedo == table_albedo and _rows(scene) == rows
    # the path tracer's set: the same draws, the same objects at the same places
    traced = make_scene(split, np.random.default_rng([0, split_id, 0]), materials="pathtrace")
    assert [r[:1] + r[2:] for r in _rows(traced)] == [r[:1] + r[2:] for r in rows]
    assert traced.table == scene.table


def test_builtin_library_is_unchanged_and_the_pathtrace_set_adds_gloss_and_metal() -> None:
    builtin, traced = object_library(), object_library("pathtrace")
    assert [o.library_id for o in builtin if o.material_id] == [7, 24, 31, 32, 38, 52, 60]
    assert [o.material_id for o in builtin if o.material_id] == [1, 1, 2, 2, 2, 1, 2]
    assert sum(o.albedo for o in builtin) == pytest.approx(34.37553807612936, abs=1e-12)
    counts = {name: sum(MATERIAL_NAMES[o.material_id] == name for o in traced)
              for name in MATERIAL_NAMES.values()}
    assert counts["glossy_plastic"] >= 8 and counts["aluminium"] + counts["steel"] >= 8
    assert counts["diffuse"] >= 16  # most objects stay diffuse
    for a, b in zip(builtin, traced, strict=True):
        assert (a.library_id, a.kind, a.dims_mm) == (b.library_id, b.kind, b.dims_mm)
        if b.material_id in METAL_IOR:
            assert b.albedo == normal_reflectance(*METAL_IOR[b.material_id])
        else:
            assert (a.material_id in (b.material_id, MATERIAL_DIFFUSE)) and a.albedo == b.albedo


def test_cli_names_the_extra_when_mitsuba_is_missing(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    def missing() -> None:
        raise SimulationError("the path-tracer reference needs mitsuba and mitransient:\n"
                              "No module named 'mitsuba'")

    monkeypatch.setattr(pathtrace_render, "load_mitsuba", missing)
    out = tmp_path / "ds"
    code = main(["sim", "dataset", "-o", str(out), "--renderer", "pathtrace", "--train-scenes", "1",
                 "--test-scenes", "0", "--views", "1", "--calibration", "1"])
    err = capsys.readouterr().err
    assert code == 2 and not out.exists()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tof-mpd sim: error: --renderer pathtrace")
    assert "pip install '.[pathtrace]'" in err and "apt-get install libllvm19" in err
    assert "No module named 'mitsuba'" in err


def test_cell_checks_its_renderer_settings() -> None:
    with pytest.raises(SimulationError, match="renderer"):
        SimCell(renderer="raster")
    with pytest.raises(SimulationError, match="pathtrace_spp"):
        SimCell(renderer="pathtrace", pathtrace_spp=100)
    with pytest.raises(SimulationError, match="hand_eye"):
        SimCell(tof=ToFConfig.nominal().with_effect("hand_eye", enabled=True),
                renderer="pathtrace")
    assert SimCell().materials == "builtin"
    assert SimCell(renderer="pathtrace").materials == "pathtrace"
    assert renderer_summary(SimCell()) == {"name": "builtin", "materials": "builtin",
                                           "calibration": "builtin", "crop": [180, 140]}


def test_pathtrace_seeds_are_a_function_of_scene_and_view() -> None:
    seeds = [pathtrace_seed(0, split, scene, view) for split in ("train", "test")
             for scene in range(3) for view in range(6)]
    assert seeds == [pathtrace_seed(0, split, scene, view) for split in ("train", "test")
                     for scene in range(3) for view in range(6)]
    assert all(0 <= s < 1 << 16 for s in seeds) and len(set(seeds)) > 30
    assert pathtrace_seed(1, "train", 0, 0) != pathtrace_seed(0, "train", 0, 0)


# --- with the [pathtrace] extra -------------------------------------------------------------

SPEC = DatasetSpec(n_train_scenes=1, n_test_scenes=1, views_per_scene=2, n_calibration=2, seed=5)


@pytest.fixture(scope="module")
def traced_dataset(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SimCell]:
    if not HAS_PATHTRACE:
        pytest.skip("the [pathtrace] extra (mitsuba) is not installed")
    cell = SimCell(camera=small_camera(), renderer="pathtrace", pathtrace_spp=32)
    out = tmp_path_factory.mktemp("traced") / "cell"
    generate_dataset(out, SPEC, cell=cell, progress=False)
    return out, cell


@needs_pathtrace
def test_traced_dataset_loads_back_and_records_its_renderer(
        traced_dataset: tuple[Path, SimCell]) -> None:
    out, _ = traced_dataset
    summary = json.loads((out / "dataset.json").read_text())
    assert summary["frames"] == {"train": 2, "test": 2, "calibration": 2}
    renderer = summary["renderer"]
    assert renderer["name"] == "pathtrace" and renderer["materials"] == "pathtrace"
    assert renderer["spp"] == 32 and renderer["max_depth"] == -1 and renderer["rr_depth"] > 8
    assert renderer["versions"]["mitsuba"].startswith("3.")
    for name in ("md_train", "md_test", "calibration"):
        with RecordingReader(out / name) as reader:
            frames = list(reader.frames())
        assert len(frames) == 2
        assert all((f.reference_mm is not None and f.pose is not None) or name == "calibration"
                   for f in frames)
        assert all(np.isfinite(f.range_mm).mean() > 0.8 for f in frames)


@needs_pathtrace
def test_traced_dataset_is_reproducible(traced_dataset: tuple[Path, SimCell]) -> None:
    out, cell = traced_dataset
    again = capture_scene("test", 0, SPEC, cell)
    with RecordingReader(out / "md_test") as reader:
        recorded = list(reader.frames())
    for a, b in zip(again.frames, recorded, strict=True):
        # the recording stores z-depth: its round trip rounds the float32 range by an ulp
        np.testing.assert_allclose(a.range_mm, b.range_mm, rtol=0, atol=1e-3)
        np.testing.assert_array_equal(a.amplitude, b.amplitude)


@needs_pathtrace
def test_traced_frames_read_the_reference_range_on_diffuse_surfaces(
        traced_dataset: tuple[Path, SimCell]) -> None:
    """On diffuse interior pixels the traced frame is within a few mm of the built-in renderer's
    frame of the same view (same sensor modules and noise draws) and within a few cm of the
    structured-light reference (the camera's offsets, cyclic error and noise)."""
    out, cell = traced_dataset
    builtin = SimCell(camera=cell.camera)
    with RecordingReader(out / "md_train") as reader:
        frames = list(reader.frames())
    scene = make_scene("train", scene_rng(SPEC.seed, "train", 0), materials="pathtrace")
    diffuse_ids = [0] + [o.scene_index for o in scene.objects
                         if o.spec.material_id == MATERIAL_DIFFUSE]
    offsets, to_builtin, amplitude_ratio = [], [], []
    for index, frame in enumerate(frames):
        pose = pose_m_to_mm(frame.pose)
        surface = render_surface(scene, pose, frame.intrinsics)
        mask = interior_mask(surface.object_id, surface.normal, half_px=1) & \
            np.isin(surface.object_id, diffuse_ids) & np.isfinite(frame.reference_mm)
        assert mask.sum() > 300
        reference = builtin.capture(scene, pose, np.random.default_rng(index),
                                    with_reference=False)
        offsets.append(frame.range_mm[mask] - frame.reference_mm[mask])
        to_builtin.append(frame.range_mm[mask] - reference.range_mm[mask])
        amplitude_ratio.append(frame.amplitude[mask] / reference.amplitude[mask])
    offsets, to_builtin = np.concatenate(offsets), np.concatenate(to_builtin)
    amplitude_ratio = np.concatenate(amplitude_ratio)
    assert abs(float(np.median(offsets))) < 25.0
    assert float(np.percentile(np.abs(offsets), 90)) < 40.0
    assert abs(float(np.median(to_builtin))) < 3.0
    assert abs(float(np.median(amplitude_ratio)) - 1.0) < 0.1  # the same amplitude units


#: a 96x72 crop of a 160x120 sensor with the DS325's field of view, and an oblique view of a box
CAMERA = CameraModel(sensor=Intrinsics.from_fov(160, 120, 74.0), crop=(96, 72), margin_px=6,
                     supersample=1)
POSE = look_at(np.array([300.0, 0.0, 400.0]), np.array([445.0, 0.0, 40.0]))
#: pure transport: footprint only, no noise or systematic errors (oracle unwrapping)
PURE = ToFConfig.ideal().with_effect("mixed_pixels", enabled=True)


def _box(material: int, albedo: float) -> Scene:
    scene = make_box_scene((120.0, 120.0, 100.0), albedo=albedo, table_albedo=0.5,
                           yaw_rad=0.35)
    box = scene.objects[0]
    spec = replace(box.spec, material_id=material)
    return Scene(scene.table, (PlacedObject(spec, 1, box.x_mm, box.y_mm, box.z_mm,
                                            box.yaw_rad),))


def _traced(scene: Scene, seed: int = 3, spp: int = 64):
    cell = SimCell(camera=CAMERA, tof=PURE, renderer="pathtrace", pathtrace_spp=spp)
    return cell.capture(scene, POSE, np.random.default_rng(0), with_reference=False,
                        pathtrace_seed=seed)


def _regions() -> dict[str, np.ndarray]:
    surface = render_surface(_box(MATERIAL_DIFFUSE, 0.5), POSE, CAMERA.intrinsics)
    inner = interior_mask(surface.object_id, surface.normal, half_px=1)
    up = (surface.normal @ POSE[:3, :3].T)[..., 2]
    regions = {"top": inner & (surface.object_id == 1) & (up > 0.9),
               "box": inner & (surface.object_id == 1),
               "table": inner & (surface.object_id == 0),
               "truth": surface.range_mm}
    assert regions["top"].sum() > 300 and regions["table"].sum() > 2000
    return regions


@needs_pathtrace
def test_diffuse_box_traced_agrees_with_the_builtin_renderer() -> None:
    regions = _regions()
    scene = _box(MATERIAL_DIFFUSE, 0.5)
    traced = _traced(scene)
    builtin = SimCell(camera=CAMERA, tof=PURE.with_effect("multipath", enabled=True)).capture(
        scene, POSE, np.random.default_rng(0), with_reference=False)
    for name in ("top", "table"):
        m = regions[name]
        diff = traced.range_mm[m] - builtin.range_mm[m]
        assert abs(float(np.median(diff))) < 0.5, name
        assert float(np.percentile(np.abs(diff), 90)) < 3.0, name
        assert abs(float(np.median(traced.amplitude[m] / builtin.amplitude[m])) - 1) < 0.03
    # the table in front of the box reads long (multipath), not the truth
    table_error = traced.range_mm[regions["table"]] - regions["truth"][regions["table"]]
    assert 0.3 < float(np.median(table_error)) < 5.0


@needs_pathtrace
@pytest.mark.parametrize("metal", [MATERIAL_ALUMINIUM, MATERIAL_STEEL])
def test_a_metal_box_returns_less_diffuse_light_than_the_same_box_diffuse(metal: int) -> None:
    regions = _regions()
    albedo = normal_reflectance(*METAL_IOR[metal])
    shiny, matte = _traced(_box(metal, albedo)), _traced(_box(MATERIAL_DIFFUSE, albedo))
    m = regions["box"]
    ratio = float(np.nanmedian(shiny.amplitude[m] / matte.amplitude[m]))
    assert ratio < 0.5, ratio  # the lobe points away from a camera that looks obliquely
    # and the metal box sends less light onto the table: less multipath there
    t = regions["table"]
    assert np.median(shiny.range_mm[t] - matte.range_mm[t]) < -0.2


@needs_pathtrace
def test_translucent_plastic_and_wax_read_long_with_their_albedo() -> None:
    regions = _regions()
    top, truth = regions["top"], regions["truth"]
    matte = _traced(_box(MATERIAL_DIFFUSE, 0.5))
    delays = {}
    for material in (MATERIAL_TRANSLUCENT_PLASTIC, MATERIAL_WAX):
        volume = _traced(_box(material, 0.5))
        delays[material] = float(np.median(volume.range_mm[top] - truth[top]))
        ratio = float(np.median(volume.amplitude[top] / matte.amplitude[top]))
        assert abs(ratio - 1.0) < 0.15, (material, ratio)  # reflects its albedo in total
    assert abs(float(np.median(matte.range_mm[top] - truth[top]))) < 0.3
    assert 2.0 < delays[MATERIAL_TRANSLUCENT_PLASTIC] < 15.0
    assert delays[MATERIAL_WAX] > delays[MATERIAL_TRANSLUCENT_PLASTIC] + 2.0  # ℓ 2 mm vs 1 mm


@needs_pathtrace
def test_traced_capture_is_a_function_of_its_seed() -> None:
    scene = _box(MATERIAL_GLOSSY_PLASTIC, 0.5)
    a, b, c = _traced(scene, seed=7, spp=16), _traced(scene, seed=7, spp=16), \
        _traced(scene, seed=8, spp=16)
    np.testing.assert_array_equal(a.range_mm, b.range_mm)
    assert not np.array_equal(a.range_mm, c.range_mm)


def test_dataset_crop_option_is_checked_before_rendering(tmp_path, capsys) -> None:
    out = tmp_path / "ds"
    args = ["sim", "dataset", "-o", str(out), "--train-scenes", "1", "--test-scenes", "0",
            "--views", "1", "--calibration", "1"]
    assert main([*args, "--crop", "400x300"]) == 2 and not out.exists()
    assert "--crop: crop 400x300 does not fit the 320x240 sensor" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([*args, "--crop", "320by240"])
    assert "expected WIDTHxHEIGHT" in capsys.readouterr().err
