//! Reliability under bad input and failures: a diverged step rolls back everything, saved
//! states are checksummed and fit their config, hand-made states with a valid checksum are
//! checked value by value, saves never share a temporary file or replace something that is
//! not a regular file, reads are bounded, scenes that do not fit in memory are refused.

mod common;
use common::*;
use rmi_sph::config::*;
use rmi_sph::simulation::Snapshot;
use rmi_sph::{RmiError, Simulation};
use std::path::PathBuf;

/// A coarse sponge (r = 1 cm) whose water, unsoaked, exceeds `max_velocity` at step 3.
fn diverging_sponge() -> SimConfig {
    let mut cfg = rmi_sph::presets::sponge([0.06, 0.06, 0.08], 0.6, 0.01);
    cfg.scene.soak_time = 0.0;
    cfg.max_velocity = 0.7;
    cfg
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("rmi-rel-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn unstable(e: RmiError) -> (u64, u64) {
    match e {
        RmiError::Unstable { step, max_velocity, .. } => (step, max_velocity.to_bits()),
        other => panic!("expected an Unstable error, got {other}"),
    }
}

#[test]
fn a_diverged_step_restores_the_whole_state_and_fails_again_the_same_way() {
    let mut sim = Simulation::new(diverging_sponge(), Some(1)).unwrap();
    let (before, kappa, fields, err) = loop {
        let before = sim.snapshot().to_bytes();
        let (kappa, fields) = (sim.kappa().to_vec(), sim.fields().porosity.clone());
        match sim.step() {
            Ok(_) => assert!(sim.step_count() < 200, "the sponge did not diverge"),
            Err(e) => break (before, kappa, fields, unstable(e)),
        }
    };
    assert!(err.0 > 1, "diverged at step {} (want a step with solver memory)", err.0);
    assert!(sim.snapshot().to_bytes() == before, "the snapshot changed");
    assert!(sim.kappa() == kappa.as_slice() && sim.fields().porosity == fields, "the fields changed");
    // A retry and a rerun from the saved last good state fail identically.
    assert_eq!(unstable(sim.step().unwrap_err()), err);
    let mut rerun = Simulation::from_snapshot(Snapshot::from_bytes(&before).unwrap(), Some(2)).unwrap();
    assert_eq!(unstable(rerun.step().unwrap_err()), err);
}

#[test]
fn every_flipped_bit_of_a_snapshot_is_refused() {
    let mut sim = Simulation::new(diverging_sponge(), Some(1)).unwrap();
    run(&mut sim, 2);
    let bytes = sim.snapshot().to_bytes();
    Snapshot::from_bytes(&bytes).unwrap();
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    for _ in 0..200 {
        seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        let bit = (seed >> 11) as usize % (8 * bytes.len());
        let mut bad = bytes.clone();
        bad[bit / 8] ^= 1 << (bit % 8);
        match Snapshot::from_bytes(&bad) {
            Err(RmiError::State(_)) => {}
            other => panic!("bit {bit} flipped: expected a state error, got {:?}", other.map(|_| ())),
        }
    }
}

#[test]
fn a_snapshot_spliced_from_another_scene_is_refused() {
    let a = Simulation::new(diverging_sponge(), Some(1)).unwrap();
    let mut other = diverging_sponge();
    other.scene.porous_blocks[0].max[2] += 0.02;
    let mut s = a.snapshot();
    s.config = other.clone();
    match Simulation::from_snapshot(s, Some(1)) {
        Err(RmiError::State(m)) => assert!(m.contains("particles"), "{m}"),
        r => panic!("expected a state error, got {:?}", r.map(|_| ())),
    }
    // Through bytes the checksum refuses any splice.
    let mut bytes = a.snapshot().to_bytes();
    let n = bytes.len();
    bytes[n / 2] ^= 0xff;
    assert!(matches!(Snapshot::from_bytes(&bytes), Err(RmiError::State(m)) if m.contains("checksum")));
}

/// The state error of `snap` sealed as the writer seals it and read back, and of the same
/// snapshot restored directly; both paths must refuse it with the same message.
fn refusal(snap: &Snapshot) -> String {
    let read = match Snapshot::from_bytes(&snap.to_bytes()) {
        Err(RmiError::State(m)) => m,
        r => panic!("expected a state error from the bytes, got {:?}", r.map(|_| ())),
    };
    match Simulation::from_snapshot(snap.clone(), Some(1)) {
        Err(RmiError::State(m)) => assert_eq!(m, read, "restoring and reading refuse differently"),
        r => panic!("expected a state error from the restore, got {:?}", r.map(|_| ())),
    }
    read
}

#[test]
fn hand_made_snapshots_with_bad_masses_are_refused() {
    let mut sim = Simulation::new(diverging_sponge(), Some(1)).unwrap();
    run(&mut sim, 2);
    let good = sim.snapshot();
    let (nf, n) = (good.particles.n_fluid, good.particles.len());
    assert!(nf > 3 && n > nf + 1, "{nf} fluid of {n} particles");
    let d = good.config.spacing();
    let range = format!("[{}, {}] kg", d * d * d, 1e5 * (d * d * d));
    for (a, mass) in [(3, f64::NAN), (3, 0.0), (n - 1, -1.0), (nf, f64::INFINITY), (3, 2e5 * d * d * d)] {
        let mut s = good.clone();
        s.particles.mass[a] = mass;
        let m = refusal(&s);
        assert!(m.starts_with(&format!("snapshot particle {a}: `mass` = {mass} kg")), "{m}");
        assert!(m.contains(&range), "{m}");
    }
    // The untouched snapshot still continues.
    let mut again = Simulation::from_snapshot(Snapshot::from_bytes(&good.to_bytes()).unwrap(), Some(1)).unwrap();
    run(&mut again, 1);
}

/// A change to a snapshot.
type Edit<'a> = dyn Fn(&mut Snapshot) + 'a;

#[test]
fn hand_made_snapshots_with_bad_ids_or_non_finite_values_are_refused() {
    let mut sim = Simulation::new(diverging_sponge(), Some(1)).unwrap();
    run(&mut sim, 2);
    let good = sim.snapshot();
    let (nf, n) = (good.particles.n_fluid, good.particles.len());
    let stretched = nalgebra::Unit::new_unchecked(nalgebra::Quaternion::new(2.0, 0.0, 0.0, 0.0));
    let cases: Vec<(Box<Edit<'_>>, String)> = vec![
        (Box::new(|s| s.particles.id[5] = s.particles.id[4]), "snapshot particle 5: `id` = ".into()),
        (Box::new(|s| s.particles.id[2] = n as u32), format!("snapshot particle 2: `id` = {n} ")),
        (Box::new(|s| s.particles.x[7].y = f64::NAN), "snapshot particle 7: `x` = [".into()),
        (Box::new(|s| s.particles.v[1].z = f64::INFINITY), "snapshot particle 1: `v` = [".into()),
        (Box::new(|s| s.dv_prev[4].x = f64::NAN), "snapshot particle 4: `dv_prev` = [".into()),
        (Box::new(|s| s.rest_positions[2].x = f64::NAN), format!("snapshot particle {}: `rest_positions` = [", nf + 2)),
        (Box::new(|s| s.kappa_dt2[6] = f64::NAN), "snapshot particle 6: `kappa_dt2` = NaN".into()),
        (Box::new(|s| s.contact_load[0] = -1.0), format!("snapshot particle {nf}: `contact_load` = -1 N")),
        (Box::new(|s| s.contact_load[1] = f64::NAN), format!("snapshot particle {}: `contact_load` = NaN N", nf + 1)),
        (Box::new(move |s| s.solid.rotation[1] = stretched), format!("snapshot particle {}: `rotation` = [", nf + 1)),
        (
            Box::new(|s| s.boundary_velocities[3].x = f64::NAN),
            "snapshot boundary particle 3: `boundary_velocities` = [".into(),
        ),
        (Box::new(|s| s.bodies[0].velocity.x = f64::NAN), "snapshot body 0: `velocity` = [".into()),
        (Box::new(move |s| s.bodies[0].rotation = stretched), "snapshot body 0: `rotation` = [".into()),
        (Box::new(|s| s.time = f64::NAN), "snapshot: `time` = NaN".into()),
    ];
    for (edit, start) in cases {
        let mut s = good.clone();
        edit(&mut s);
        let m = refusal(&s);
        assert!(m.starts_with(&start) && m.contains("is not accepted; expected"), "{start}: {m}");
    }
    let mut s = good.clone();
    s.particles.id[5] = s.particles.id[4];
    let m = refusal(&s);
    assert!(m.contains(&format!("[0, {n})")) && m.contains("particle 4 holds it"), "{m}");
}

#[test]
fn concurrent_saves_keep_each_file_its_own_state() {
    let dir = scratch("concurrent");
    let sims: Vec<Simulation> = [0.0, 0.01]
        .iter()
        .map(|dz| {
            let mut cfg = diverging_sponge();
            cfg.max_velocity = 10.0;
            cfg.scene.porous_blocks[0].max[2] += dz;
            Simulation::new(cfg, Some(1)).unwrap()
        })
        .collect();
    let paths = [dir.join("ck.a"), dir.join("ck.b")];
    std::thread::scope(|s| {
        for (sim, path) in sims.iter().zip(&paths) {
            s.spawn(move || {
                for _ in 0..40 {
                    sim.save(path).unwrap();
                }
            });
        }
    });
    for (sim, path) in sims.iter().zip(&paths) {
        assert!(std::fs::read(path).unwrap() == sim.snapshot().to_bytes(), "{} holds another state", path.display());
    }
    let left: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 2, "temporary files left behind: {left:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn saves_replace_only_regular_files_and_reads_are_bounded() {
    let dir = scratch("special");
    let sim = Simulation::new(diverging_sponge(), Some(1)).unwrap();
    let target = dir.join("target");
    std::fs::write(&target, b"keep").unwrap();
    let link = dir.join("link");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    let fifo = dir.join("fifo");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let sub = dir.join("sub");
    std::fs::create_dir(&sub).unwrap();
    for path in [&link, &fifo] {
        match sim.save(path) {
            Err(RmiError::Io(e)) => assert!(e.to_string().contains(&*path.to_string_lossy()), "{e}"),
            r => panic!("{}: expected an io error, got {r:?}", path.display()),
        }
    }
    // A directory: the system's own error, as a write to it would give.
    assert!(matches!(sim.save(&sub), Err(RmiError::Io(e)) if e.raw_os_error() == Some(21)));
    assert_eq!(std::fs::read(&target).unwrap(), b"keep", "the symlink's target was written");
    for path in [&fifo, &sub, &PathBuf::from("/dev/zero")] {
        assert!(matches!(Simulation::load(path, Some(1)), Err(RmiError::Io(_))), "{}", path.display());
    }
    let e = rmi_sph::simulation::read_limited(&target, 3, "config file").unwrap_err().to_string();
    assert!(e.contains("limit of 3 bytes"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_memory_estimate_bounds_what_a_simulation_holds() {
    for (name, cfg) in [
        ("water", rmi_sph::presets::water_column(0.01, 0.2, 0.2)),
        ("sponge", rmi_sph::presets::sponge([0.08, 0.08, 0.12], 0.6, 0.005)),
    ] {
        let mut sim = Simulation::new(cfg.clone(), Some(1)).unwrap();
        run(&mut sim, 2);
        let (f, s, b) = cfg.estimated_counts();
        let p = sim.particles();
        let close = |e: f64, n: usize| e >= 0.95 * n as f64;
        assert!(close(f, p.n_fluid) && close(s, p.n_solid()), "{name}: {f} {s} vs {} {}", p.n_fluid, p.n_solid());
        assert!(close(b, sim.boundary().x.len()), "{name}: boundary {b} vs {}", sim.boundary().x.len());
        let held = sim.memory_bytes() as f64;
        assert!(cfg.estimated_bytes() >= 1.5 * held, "{name}: estimate {} vs held {held}", cfg.estimated_bytes());
    }
    // A floor of 2 km at r = 1 mm: billions of boundary particles, refused before building.
    let mut cfg = rmi_sph::presets::water_column(0.001, 0.01, 0.01);
    cfg.scene.bodies.push(BodyConfig {
        name: "huge floor".into(),
        shape: Shape::Box { half_extents: [1000.0, 1000.0, 0.01] },
        position: [0.0, 0.0, -1.0],
        rotation: [0.0; 3],
        kinematic: false,
    });
    let e = Simulation::new(cfg.clone(), Some(1)).unwrap_err().to_string();
    assert!(e.contains("particle_radius") && e.contains("boundary") && e.contains("GB"), "{e}");
    let e = rmi_sph::presets::water_column(0.01, 0.2, 0.2).check_memory(1e3).unwrap_err().to_string();
    assert!(e.contains("particle_radius") && e.contains("available"), "{e}");
}
