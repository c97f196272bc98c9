//! Atomic files and batches: a failed write replaces nothing and leaves no temporary
//! file behind (docs/robustness.md "Nothing lost").

use std::path::{Path, PathBuf};

use iastgcn::atomic::{self, Batch};

fn folder(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("iastgcn-atomic-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn a_batch_replaces_all_of_its_files_or_none() {
    let dir = folder("batch");
    let (a, b) = (dir.join("a.txt"), dir.join("b.txt"));
    std::fs::write(&a, "old a").unwrap();
    std::fs::write(&b, "old b").unwrap();

    // The second file cannot be written (its folder does not exist): nothing replaced.
    let mut batch = Batch::new();
    batch.add(&a, b"new a").unwrap();
    assert!(batch.add(&dir.join("missing/b.txt"), b"new b").is_err());
    drop(batch);
    assert_eq!(std::fs::read_to_string(&a).unwrap(), "old a");
    assert_eq!(names(&dir), ["a.txt", "b.txt"], "no temporary file left");

    // A writer that fails (an image encoder, say): nothing replaced either.
    let mut batch = Batch::new();
    batch.add(&a, b"new a").unwrap();
    let failed: Result<(), String> = batch.add_with(&b, |tmp| {
        std::fs::write(tmp, "half").unwrap();
        Err("encoder failed".into())
    });
    assert_eq!(failed.unwrap_err(), "encoder failed");
    drop(batch);
    assert_eq!(std::fs::read_to_string(&b).unwrap(), "old b");
    assert_eq!(names(&dir), ["a.txt", "b.txt"]);

    // A target that is a folder fails the commit before any rename.
    std::fs::create_dir(dir.join("c.txt")).unwrap();
    let mut batch = Batch::new();
    batch.add(&a, b"new a").unwrap();
    batch.add(&dir.join("c.txt"), b"new c").unwrap();
    let err = batch.commit().unwrap_err().to_string();
    assert!(err.contains("c.txt") && err.contains("folder"), "{err}");
    assert_eq!(std::fs::read_to_string(&a).unwrap(), "old a");
    assert_eq!(names(&dir), ["a.txt", "b.txt", "c.txt"]);

    // All written: all replaced.
    let mut batch = Batch::new();
    batch.add(&a, b"new a").unwrap();
    batch
        .add_with(&b, |tmp| std::fs::write(tmp, "new b"))
        .unwrap();
    batch.commit().unwrap();
    assert_eq!(std::fs::read_to_string(&a).unwrap(), "new a");
    assert_eq!(std::fs::read_to_string(&b).unwrap(), "new b");
    assert_eq!(names(&dir), ["a.txt", "b.txt", "c.txt"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_full_disk_leaves_the_old_file_and_no_temporary() {
    // A file-size limit makes every write past 512 bytes fail with EFBIG, as a full
    // disk fails it with ENOSPC (SIGXFSZ ignored, so the write returns the error
    // instead of killing the process).
    let dir = folder("full");
    let target = dir.join("model.safetensors");
    std::fs::write(&target, "old").unwrap();
    let o = std::process::Command::new("bash")
        .arg("-c")
        .arg(format!(
            "trap '' XFSZ; ulimit -f 1; exec '{}' init --out '{}'",
            env!("CARGO_BIN_EXE_iastgcn"),
            target.display()
        ))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success(),
        "the write succeeded under a 512-byte limit"
    );
    assert!(err.contains("model.safetensors"), "names the file: {err}");
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "old");
    assert_eq!(names(&dir), ["model.safetensors"], "no temporary file left");

    // The library call says the same.
    let bad = dir.join("no-such-folder").join("model.safetensors");
    let e = atomic::write(&bad, b"new").unwrap_err();
    assert_eq!(e.kind(), std::io::ErrorKind::NotFound);
    assert_eq!(names(&dir), ["model.safetensors"]);
    std::fs::remove_dir_all(&dir).unwrap();
}
