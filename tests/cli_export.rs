//! `prism export`: the written NIfTI, MetaImage and TIFF files read back by the tools our users
//! open them with — nibabel and ITK (PyPI) — with the same values, spacing, origin and orientation.
//! Skipped with a message where Python lacks them, unless `PRISM_REQUIRE_PY_READERS` is set
//! (`.ci/run` installs them and sets it, so CI never skips).

mod common;

use common::{path, phantom_config, prism};
use std::process::Command;

const READ_BACK: &str = r#"
import sys, numpy as np, nibabel as nib, itk
out, scene = sys.argv[1], sys.argv[2]
refs = np.load(f"{scene}/references.npy")           # [channel][z][y][x]
ref = refs[0]
n, d, centre = ref.shape[2], 8.0, np.array([5.0, -7.0, 3.0])
first = centre + (0.5 - n / 2) * d                   # world position of voxel (0, 0, 0)
# nibabel: data indexed [x][y][z], the affine as written (scanner frame, mm).
img = nib.load(f"{out}/reference-40keV.nii.gz")
want = np.diag([d, d, d, 1.0]); want[:3, 3] = first
assert np.allclose(img.affine, want), img.affine
assert img.header.get_xyzt_units()[0] == "mm"
assert np.array_equal(np.asarray(img.dataobj, dtype=np.float32), ref.transpose(2, 1, 0))
# ITK, MetaImage: arrays come back [z][y][x]; spacing, origin, identity direction.
m = itk.imread(f"{out}/reference-40keV.mha")
assert np.array_equal(itk.array_from_image(m), ref)
assert np.allclose(tuple(m.GetSpacing()), (d, d, d))
assert np.allclose(tuple(m.GetOrigin()), first)
assert np.allclose(itk.array_from_matrix(m.GetDirection()), np.eye(3))
# ITK, NIfTI: the same voxels; its LPS frame flips x and y of the origin and the direction.
k = itk.imread(f"{out}/reference-40keV.nii.gz")
assert np.array_equal(itk.array_from_image(k), ref)
assert np.allclose(tuple(k.GetOrigin()), first * np.array([-1, -1, 1]))
assert np.allclose(itk.array_from_matrix(k.GetDirection()), np.diag([-1.0, -1.0, 1.0]))
# ITK, TIFF stack: one page per z slice, the same voxels.
t = itk.imread(f"{out}/reference-40keV.tif")
assert np.array_equal(itk.array_from_image(t), ref)
# A second channel and the uncompressed NIfTI hold their own data.
assert np.array_equal(np.asarray(nib.load(f"{out}/reference-100keV.nii").dataobj), refs[2].transpose(2, 1, 0))
print("read back: ok")
"#;

fn readers_available() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import numpy, nibabel, itk"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        assert!(
            std::env::var_os("PRISM_REQUIRE_PY_READERS").is_none(),
            "PRISM_REQUIRE_PY_READERS is set but python3 cannot import numpy, nibabel and itk"
        );
        eprintln!(
            "skipped: python3 with numpy, nibabel and itk not found (pip install nibabel itk)"
        );
    }
    ok
}

#[test]
fn exported_volumes_read_back_in_nibabel_and_itk_with_their_geometry() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("p.yaml");
    std::fs::write(&config, phantom_config("p", 8, 16, 16, &[40, 70, 100])).unwrap();
    let scene = dir.path().join("scene");
    let (ok, t) = prism(&[
        "simulate",
        path(&config),
        "-o",
        path(&scene),
        "--set",
        "geometry.volume.size_mm=128",
        "--set",
        "geometry.volume.offset_mm=[5.0, -7.0, 3.0]",
    ]);
    assert!(ok, "{t}");
    let out = dir.path().join("export");
    let (ok, t) = prism(&[
        "export",
        path(&scene),
        "-o",
        path(&out),
        "--format",
        "nii.gz",
        "--format",
        "nii",
        "--format",
        "mha",
        "--format",
        "tif",
        "--format",
        "png",
    ]);
    assert!(ok, "{t}");
    assert!(
        std::fs::read(out.join("reference-40keV.png"))
            .unwrap()
            .starts_with(b"\x89PNG")
    );
    assert!(t.contains("reference-70keV.mha"), "{t}");
    // Refusals name what is wrong.
    let (ok, t) = prism(&["export", path(&scene), "-o", path(&out), "--format", "nrrd"]);
    assert!(!ok && t.contains("unknown volume format `nrrd`"), "{t}");
    let (ok, t) = prism(&[
        "export",
        path(&scene),
        path(&scene.join("projections.npy")),
        "-o",
        path(&out),
        "--format",
        "mha",
    ]);
    assert!(!ok && t.contains("projections.npy"), "{t}");
    if !readers_available() {
        return;
    }
    let o = Command::new("python3")
        .args(["-c", READ_BACK, path(&out), path(&scene)])
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        o.status.success() && text.contains("read back: ok"),
        "{text}"
    );
}
