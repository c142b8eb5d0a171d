"""prism.reconstruct runs every method of `prism recon` on arrays, writes and reads back run
directories, reports progress and stops on Ctrl-C."""

import _thread
import signal
import threading

import numpy as np
import pytest

import prism

KEV = [40, 70, 100]


@pytest.fixture(scope="module")
def scene():
    g = prism.Geometry.cone(
        dso=300.0, dsd=500.0, rows=40, cols=48, pitch=1.2,
        volume=(24, 24, 24), voxel=1.0, angles=prism.full_turn(20),
    )
    z, y, x = np.meshgrid(*[np.arange(24) + 0.5 - 12] * 3, indexing="ij")
    inner = x**2 + (y - 2) ** 2 + z**2 <= 16
    refs = np.stack([
        np.where(x**2 + y**2 + z**2 <= 64, mu, 0) + np.where(inner, extra, 0)
        for mu, extra in [(0.03, 0.02), (0.02, 0.008), (0.015, 0.004)]
    ]).astype(np.float32)
    p = np.stack([prism.project(r, g) for r in refs])
    return g, p, refs


SHORT = {
    "fdk": None,
    "sart": {"iterations": 3},
    "cgls": {"iterations": 5},
    "tv": {"iterations": 10},
    "r2gs": {"iterations": 30, "eval_every": 15, "init": {"n_points": 1000}},
    "4dsg": {"iterations": 30, "eval_every": 15, "init": {"n_points": 1000}, "stage2": {"iterations": 10}},
    "naf": {"iterations": 4, "eval_every": 2, "rays_per_batch": 256, "samples_per_ray": 32},
}


@pytest.mark.parametrize("method", list(SHORT))
def test_every_method_reconstructs_the_channels(scene, method):
    g, p, refs = scene
    run = prism.reconstruct(p, g, method=method, config=SHORT[method], channels=KEV, references=refs)
    assert run.dir is None
    assert sorted(run.volumes) == ["100keV", "40keV", "70keV"]
    for v in run.volumes.values():
        assert v.shape == g.volume_shape and v.dtype == np.float32 and np.isfinite(v).all()
    assert set(run.metrics["mean"]) >= {"psnr", "ssim"}
    assert f"method: {method}" in run.config
    if method in ("r2gs", "4dsg", "naf"):
        assert any("psnr" in entry for entry in run.log)


def test_a_run_directory_is_written_and_read_back(scene, tmp_path):
    g, p, refs = scene
    run = prism.reconstruct(p, g, method="fdk", channels=KEV, references=refs, out=tmp_path / "fdk")
    again = prism.load_run(tmp_path / "fdk")
    assert run.dir == again.dir == tmp_path / "fdk"
    for label, v in run.volumes.items():
        assert np.array_equal(v, again.volumes[label])
    assert again.metrics == run.metrics
    with pytest.raises(ValueError, match="is not empty"):
        prism.reconstruct(p, g, method="fdk", channels=KEV, out=tmp_path / "fdk")
    prism.reconstruct(p, g, method="fdk", channels=KEV, out=tmp_path / "fdk", force=True)
    with pytest.raises(ValueError, match="not a run directory"):
        prism.load_run(tmp_path)


def test_one_channel_and_interleaved_availability(scene):
    g, p, refs = scene
    one = prism.reconstruct(p[0], g, method="fdk")
    assert list(one.volumes) == ["channel"]
    availability = np.zeros((g.views, 3), bool)
    for v in range(g.views):
        availability[v, v % 3] = True
    run = prism.reconstruct(p, g, method="r2gs", config=SHORT["r2gs"], channels=KEV,
                            availability=availability, references=refs)
    assert sorted(run.volumes) == ["100keV", "40keV", "70keV"]


def test_channels_take_any_spectral_coordinate(scene):
    g, p, _ = scene
    kvp = [{"label": "low", "kind": "tube_voltage", "kvp": 80}, {"kind": "tube_voltage", "kvp": 100},
           {"kind": "tube_voltage", "kvp": 140}]
    assert sorted(prism.reconstruct(p, g, method="fdk", channels=kvp).volumes) == ["100kVp", "140kVp", "low"]
    bins = [{"kind": "window", "lo_kev": lo, "hi_kev": lo + 15} for lo in (20, 35, 50)]
    assert sorted(prism.reconstruct(p, g, method="fdk", channels=bins).volumes) == [
        "20-35keV", "35-50keV", "50-65keV"
    ]
    # One coordinate kind per scan, as a scene.yaml requires; the message names the channel.
    with pytest.raises(ValueError, match=r"channels\[2\].coordinate"):
        prism.reconstruct(p, g, method="fdk", channels=kvp[:2] + bins[:1])


def test_bad_calls_name_what_is_wrong(scene):
    g, p, _ = scene
    with pytest.raises(ValueError, match="channels: 3 channels need"):
        prism.reconstruct(p, g, method="fdk")
    with pytest.raises(ValueError, match="channels: 2 given for 3"):
        prism.reconstruct(p, g, method="fdk", channels=[40, 70])
    with pytest.raises(ValueError, match="method"):
        prism.reconstruct(p, g, method="nope", channels=KEV)
    with pytest.raises(ValueError, match="iterations"):
        prism.reconstruct(p, g, method="sart", config={"iterations": 0}, channels=KEV)
    with pytest.raises(ValueError, match="availability"):
        prism.reconstruct(p, g, method="fdk", channels=KEV, availability=np.ones((3, 3), bool))


def test_progress_reaches_the_callback(scene):
    g, p, _ = scene
    seen = []
    prism.reconstruct(p, g, method="r2gs", config=SHORT["r2gs"], channels=KEV,
                      progress=lambda kind, a, b: seen.append((kind, a, b)))
    phases = [a for kind, a, _ in seen if kind == "phase"]
    assert phases and any(kind == "progress" for kind, _, _ in seen), seen[:5]


def test_ctrl_c_stops_a_training_run(scene, tmp_path):
    g, p, _ = scene
    # A shell's background job starts with SIGINT ignored, and interrupt_main then does nothing (the run
    # would go on for all its iterations): handle SIGINT as an interactive Python does.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(1.0, _thread.interrupt_main)
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt, match="interrupted"):
            prism.reconstruct(p, g, method="r2gs", config={"iterations": 100000}, channels=KEV,
                              out=tmp_path / "long")
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    # The state is saved for --resume, as the command line's SIGINT does; nothing is published.
    assert (tmp_path / "long.resume.safetensors").is_file()
    assert not (tmp_path / "long").exists()


def test_a_trained_spectral_run_answers_queries(scene, tmp_path):
    g, p, refs = scene
    run = prism.reconstruct(p, g, method="4dsg", config=SHORT["4dsg"], channels=KEV, out=tmp_path / "sg")
    at40 = prism.query(run, kev=40)
    # At an observed channel the curves are that channel's densities: the run's own volume.
    assert np.allclose(at40, run.volumes["40keV"], atol=1e-6)
    between = prism.query(tmp_path / "sg", coordinate=55)
    lo, hi = run.volumes["70keV"], run.volumes["40keV"]
    # Linear in the raw densities between 40 and 70 keV: the softplus keeps it between them.
    assert between.shape == g.volume_shape
    assert np.all(between <= np.maximum(lo, hi) + 1e-6) and np.all(between >= np.minimum(lo, hi) - 1e-6)
    assert prism.query(run, tau=0.0, projections=True).shape == g.projection_shape
    with pytest.raises(ValueError, match="extrapolat"):
        prism.query(run, kev=120)
    assert np.isfinite(prism.query(run, kev=120, extrapolate=True)).all()
    with pytest.raises(ValueError, match="exactly one"):
        prism.query(run, kev=40, tau=0.5)
    with pytest.raises(ValueError, match="temporary"):
        prism.query(prism.reconstruct(p, g, method="fdk", channels=KEV))


def test_a_run_too_large_for_the_memory_is_refused_before_it_starts(scene, tmp_path):
    g, p, _ = scene
    # At a cap of a billion Gaussians R²-Gaussian's estimated peak is terabytes.
    huge = {"densify": {"max_gaussians": 1_000_000_000}}
    with pytest.raises(ValueError, match="needs about .* at its peak"):
        prism.reconstruct(p, g, method="r2gs", config=huge, channels=KEV, out=tmp_path / "big")
    assert not (tmp_path / "big").exists()
