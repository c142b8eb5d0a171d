//! Outputs and the user's files, one test per data-loss cause the reliability sweep found (#39);
//! each failed before its fix:
//!
//! | cause | test |
//! |---|---|
//! | `--force` beside a `.NAME.old` that cannot be removed | `a_leftover_that_cannot_be_removed_keeps_the_users_files` |
//! | two `decompose` into one directory | `a_decompose_into_a_directory_being_written_is_refused` |
//! | `export` / `query -o` replacing files (and export's 0600 files) | `outputs_never_replace_a_file_without_force` |

mod common;

use common::{STAGE2, path, prism, run_4dsg, with_fdk};
use std::path::Path;

#[test]
fn a_leftover_that_cannot_be_removed_keeps_the_users_files() {
    let (dir, scene, fdk) = with_fdk("old", &[40]);
    let out = dir.path().join("run");
    let recon = || {
        prism(&[
            "recon",
            path(&fdk),
            "-s",
            path(&scene),
            "-o",
            path(&out),
            "--force",
        ])
    };
    let (ok, t) = recon();
    assert!(ok, "{t}");
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    // `.run.old` is a file: removing it as a directory fails (also for root).
    std::fs::write(dir.path().join(".run.old"), "in the way").unwrap();
    let (ok, t) = recon();
    assert!(!ok && t.contains(".run.old"), "{t}");
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).unwrap(),
        "mine"
    );
    assert!(out.join("metrics.json").is_file());
    std::fs::remove_file(dir.path().join(".run.old")).unwrap();
    let (ok, t) = recon();
    assert!(ok, "{t}");
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).unwrap(),
        "mine"
    );
}

#[test]
fn a_decompose_into_a_directory_being_written_is_refused() {
    let (dir, scene, fdk) = with_fdk("dec", &[40, 70]);
    let run = dir.path().join("run");
    let (ok, t) = prism(&["recon", path(&fdk), "-s", path(&scene), "-o", path(&run)]);
    assert!(ok, "{t}");
    let out = dir.path().join("dec");
    // Another live process (this test) is writing `dec`.
    let staging = dir.path().join(".dec.partial");
    std::fs::create_dir(&staging).unwrap();
    std::fs::write(
        staging.join(".prism-writer"),
        std::process::id().to_string(),
    )
    .unwrap();
    let decompose = || {
        prism(&[
            "decompose",
            path(&run),
            "-s",
            path(&scene),
            "-o",
            path(&out),
            "--basis",
            "water,cortical_bone",
            "--kev",
            "60",
        ])
    };
    let (ok, t) = decompose();
    assert!(!ok && t.contains("another prism process"), "{t}");
    assert!(!out.exists());
    std::fs::remove_dir_all(&staging).unwrap();
    let (ok, t) = decompose();
    assert!(ok, "{t}");
    let mut names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert!(names.contains(&"vmi-60keV.npy".to_string()), "{names:?}");
    assert!(!dir.path().join(".dec.partial").exists());
}

#[test]
fn outputs_never_replace_a_file_without_force() {
    let (dir, scene, run) = run_4dsg(STAGE2);
    // query -o onto the run's own volume: refused, the volume intact.
    let own = run.join("40keV.npy");
    let before = std::fs::read(&own).unwrap();
    let (ok, t) = prism(&["query", path(&run), "--tau", "0.5", "-o", path(&own)]);
    assert!(
        !ok && t.contains("--force") && t.contains("40keV.npy"),
        "{t}"
    );
    assert_eq!(std::fs::read(&own).unwrap(), before);
    // export over a user's file: refused before anything is written.
    let out = dir.path().join("exported");
    std::fs::create_dir(&out).unwrap();
    std::fs::write(out.join("40keV.mha"), "mine").unwrap();
    let export = |force: bool| {
        let mut args = vec![
            "export",
            path(&scene),
            path(&run),
            "-o",
            path(&out),
            "--format",
            "nii",
            "--format",
            "mha",
        ];
        if force {
            args.push("--force");
        }
        prism(&args)
    };
    let (ok, t) = export(false);
    assert!(
        !ok && t.contains("40keV.mha") && t.contains("--force"),
        "{t}"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("40keV.mha")).unwrap(),
        "mine"
    );
    assert!(!out.join("40keV.nii").exists(), "nothing written");
    let (ok, t) = export(true);
    assert!(ok, "{t}");
    // Written with the user's umask, as a file this process creates.
    use std::os::unix::fs::PermissionsExt;
    let probe = dir.path().join("probe");
    std::fs::write(&probe, "").unwrap();
    let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode(&out.join("40keV.nii")), mode(&probe));
    let q = dir.path().join("q.npy");
    let (ok, t) = prism(&["query", path(&run), "--tau", "0.5", "-o", path(&q)]);
    assert!(ok, "{t}");
    assert_eq!(mode(&q), mode(&probe));
}
