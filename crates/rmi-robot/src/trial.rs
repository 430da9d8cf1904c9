//! A grasp-lift-squeeze trial: the porous simulation with the two pads, contact memory,
//! the controller and the lift gate, stepped together and observed every step.
//!
//! [`Trial`] is the robot environment (step it, read [`Observation`]s, drive it with an
//! external [`Action`]); [`run_trial`] runs the scripted trial to the end and returns the
//! recorded trajectory and its outcome.

use crate::config::TrialConfig;
use crate::controller::{Action, ControlInput, Controller, Failure, Phase, Transition};
use crate::gate::{Gate, GateInput};
use crate::gripper::{Gripper, FORCE_LIMIT, LIFT_AXIS};
use crate::observe::{summarise, Observation};
use nalgebra::Vector3;
use rmi_sph::config::check_range;
use rmi_sph::contact::ContactMemory;
use rmi_sph::simulation::{read_state, seal, unseal, write_atomic, Snapshot};
use rmi_sph::{Result, RmiError, Simulation};
use serde::{Deserialize, Serialize};

/// How a trial ended.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Outcome {
    /// The sponge was lifted and held through the waiting phase.
    pub lift_success: bool,
    /// The squeeze completed with the sponge still held.
    pub stable_squeeze: bool,
    /// Why the trial ended early, if it did.
    pub failure: Option<String>,
    /// Time the lift gate opened (s).
    pub gate_opened_at: Option<f64>,
    /// Retained water lost during each phase (kg), by phase name, in phase order.
    pub water_removed: Vec<(String, f64)>,
    /// Retained water at the start (kg).
    pub initial_water: f64,
    /// Retained water at the end (kg).
    pub final_water: f64,
    /// Total liquid mass in the scene (kg).
    pub total_water: f64,
    /// Simulated time (s).
    pub sim_time: f64,
    /// Simulator steps.
    pub steps: u64,
    /// Wall-clock time of the run (s).
    pub wall_s: f64,
    /// Fluid particles.
    pub n_fluid: usize,
    /// Skeleton particles.
    pub n_solid: usize,
}

/// Serialisable state of the robot layer beside the simulation.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct Layer {
    memory: ContactMemory,
    controller: Controller,
    gate: Gate,
    obs: Observation,
    load_sum: LoadSum,
    /// Each phase entered and the retained water at its entry (kg).
    phase_water: Vec<(Phase, f64)>,
    initial_water: f64,
    /// The water the sponge's pores held when the trial started (kg), the reference of
    /// [`Trial::retained`].
    pore_water0: f64,
}

/// Sums of the pad loads (N) and the wrist load (N) over the engine steps of one recording
/// interval.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
struct LoadSum {
    left: f64,
    right: f64,
    wrist: [f64; 3],
    steps: u32,
}

/// Header of a trial state; a checksum of header and payload follows the payload.
const MAGIC: &[u8; 8] = b"RMITRL04";
/// Headers of older states, not readable any more: before the checksum, and before the
/// wrist load.
const OLD_MAGICS: [&[u8; 8]; 2] = [b"RMITRIAL", b"RMITRL03"];

/// A trial in progress: the robot environment.
pub struct Trial {
    cfg: TrialConfig,
    sim: Simulation,
    gripper: Gripper,
    friction_bodies: Vec<bool>,
    layer: Layer,
}

impl Trial {
    /// Builds the scene and the robot layer; `threads = None` uses the default count.
    pub fn new(cfg: TrialConfig, threads: Option<usize>) -> Result<Self> {
        cfg.validate()?;
        let cfg = cfg.normalised();
        let sim = Simulation::new(cfg.sim_config(), threads)?;
        Self::around(cfg, sim)
    }

    /// The robot layer around a built scene.
    fn around(cfg: TrialConfig, mut sim: Simulation) -> Result<Self> {
        sim.update_fields();
        let gripper = Gripper::find(sim.boundary(), cfg.gripper.thickness)
            .ok_or_else(|| RmiError::State("the scene has no gripper pads".into()))?;
        let n_solid = sim.particles().n_solid();
        let layer = Layer {
            memory: ContactMemory::new(n_solid),
            controller: Controller::new(cfg.hold_force, cfg.squeeze_force),
            gate: Gate::default(),
            obs: Observation::default(),
            load_sum: LoadSum::default(),
            phase_water: Vec::new(),
            initial_water: 0.0,
            pore_water0: sim.pore_water(0),
        };
        let friction_bodies = vec![true; sim.boundary().bodies.len()];
        let mut t = Trial { cfg, sim, gripper, friction_bodies, layer };
        t.layer.obs = t.observe(&[]).0;
        t.layer.initial_water = t.layer.obs.m_l;
        t.layer.phase_water.push((Phase::Settle, t.layer.obs.m_l));
        Ok(t)
    }

    /// The configuration.
    pub fn config(&self) -> &TrialConfig {
        &self.cfg
    }

    /// The underlying simulation.
    pub fn simulation(&self) -> &Simulation {
        &self.sim
    }

    /// The pads.
    pub fn gripper(&self) -> &Gripper {
        &self.gripper
    }

    /// The latest observation (instantaneous loads of the last step).
    pub fn observation(&self) -> &Observation {
        &self.layer.obs
    }

    /// Current phase.
    pub fn phase(&self) -> Phase {
        self.layer.controller.phase
    }

    /// The controller state.
    pub fn controller(&self) -> &Controller {
        &self.layer.controller
    }

    /// The lift gate.
    pub fn gate(&self) -> &Gate {
        &self.layer.gate
    }

    /// The contact memory.
    pub fn memory(&self) -> &ContactMemory {
        &self.layer.memory
    }

    /// Whether the trial is over.
    pub fn finished(&self) -> bool {
        self.phase() == Phase::Done
    }

    /// Why it ended early, if it did.
    pub fn failure(&self) -> Option<Failure> {
        self.layer.controller.failure
    }

    /// Drives the gripper with `u_t` from now on (`None` returns to the scripted targets).
    /// The phase sequence, the gate and the guards keep running.
    pub fn set_action(&mut self, action: Option<Action>) -> Result<()> {
        if let Some(a) = &action {
            a.validate()?;
        }
        self.layer.controller.external = action;
        Ok(())
    }

    /// Retained liquid (kg) and the total liquid mass (kg). The sponge starts holding all the
    /// water; what its pores lose since ([`Simulation::pore_water`]) is expelled:
    /// `M_L = total - clamp(P0 - P, 0, total)`. (The sampled pore water and the pores' nominal
    /// volume differ by the lattice's rounding, a few per cent, so the pores' water is
    /// counted by its change, in physical units.) `pore_water` (kg) is the pores' water now.
    fn retained(&self, pore_water: f64) -> (f64, f64) {
        let total = self.total_water();
        let lost = (self.layer.pore_water0 - pore_water).clamp(0.0, total);
        (total - lost, total)
    }

    /// The liquid's mass (kg).
    fn total_water(&self) -> f64 {
        let p = self.sim.particles();
        p.mass[..p.n_fluid].iter().sum()
    }

    /// The observation after a step with these friction records, and the sponge's centre of
    /// mass height along the lift axis (m), which the phase transitions need.
    fn observe(&self, records: &[rmi_sph::contact::ContactFriction]) -> (Observation, f64) {
        let b = self.sim.boundary();
        let (f_l, f_r) = self.gripper.loads(b);
        let s = summarise(records, self.gripper.left, self.gripper.right);
        // One pass over the skeleton for the volumes and the pores' water.
        let (v_sponge, v_pore, sat) = self.sim.sponge_volumes(0);
        let (m_l, total) = self.retained(self.sim.pore_water_of(v_pore, sat));
        let (_, com, v_com) = self.sim.object_motion(0);
        let d = 2.0 * self.cfg.particle_radius;
        let c = &self.layer.controller;
        let obs = Observation {
            time: self.sim.time(),
            phase: Some(c.phase),
            m_l,
            saturation: sat,
            v_pore,
            v_sponge,
            width: self.gripper.width(b),
            f_meas: 0.5 * (f_l + f_r),
            f_l,
            f_r,
            a_l: s.count.0 as f64 * d * d,
            a_r: s.count.1 as f64 * d * d,
            contact: s.count.0 > 0 && s.count.1 > 0,
            v_tan: s.v_tan.into(),
            f_fric: s.f_fric.into(),
            v_res: s.v_res,
            regime: s.regime,
            f_target: c.last.force_target,
            v_cmd: c.last.v_cmd,
            v_com: v_com.into(),
            gate_open: self.layer.gate.opened_at.is_some(),
            m_expelled: total - m_l,
            lift_height: c.lift_start.map_or(0.0, |h0| self.gripper.height(b) - h0),
            wrist_load: self.gripper.wrist_load(b).into(),
        };
        (obs, com.dot(&LIFT_AXIS))
    }

    fn control_input(&self) -> ControlInput {
        let f = self.layer.gate.filtered;
        ControlInput { time: self.sim.time(), force: 0.5 * (f.0 + f.1), width: self.gripper.width(self.sim.boundary()) }
    }

    /// Advances one simulator step: command, pad motion, porous step with friction, observe,
    /// gate, phase transitions. On an error nothing changes.
    pub fn step(&mut self) -> Result<&Observation> {
        let p = self.cfg.controller.clone();
        let saved_ctrl = self.layer.controller.clone();
        // The pads' velocities, set before the step: restored with the rest if it diverges.
        let pads = [self.gripper.left, self.gripper.right].map(|bi| {
            let s = &self.sim.boundary().bodies[bi].state;
            (bi, s.velocity, s.angular_velocity)
        });
        let cmd = self.layer.controller.command(&p, &self.control_input());
        for (bi, v) in self.gripper.velocities(cmd.v_cmd, cmd.lift_speed) {
            self.sim.set_body_velocity(bi, v, Vector3::zeros())?;
        }
        let mut memory = self.layer.memory.clone();
        let mut records = Vec::new();
        let (bodies, fp) = (&self.friction_bodies, &self.cfg.friction);
        // Uncoupled friction is applied by the hook alone: no law and no anchors in the solves.
        let sticks = fp.coupled.then(|| memory.sticks(self.sim.particles().n_fluid, self.sim.boundary()));
        let law = sticks.as_deref().map(|s| fp.law(s, bodies));
        let out = &mut records;
        let mem = &mut memory;
        if let Err(e) = self.sim.step_with_friction(law.as_ref(), move |stage| *out = mem.apply(stage, bodies, fp)) {
            self.layer.controller = saved_ctrl;
            for (bi, v, w) in pads {
                self.sim.set_body_velocity(bi, v, w)?;
            }
            return Err(e);
        }
        self.layer.memory = memory;
        let b = self.sim.boundary();
        let loads = self.gripper.loads(b);
        self.layer.gate.filter(&self.cfg.gate, loads);
        let wrist = self.gripper.wrist_load(b);
        let ls = &mut self.layer.load_sum;
        ls.left += loads.0;
        ls.right += loads.1;
        for (s, w) in ls.wrist.iter_mut().zip(wrist.iter()) {
            *s += w;
        }
        ls.steps += 1;
        let (mut obs, sponge_height) = self.observe(&records);
        let bilateral = obs.contact;
        if self.layer.controller.phase == Phase::Hold {
            let x = GateInput {
                loads,
                hold_force: self.cfg.hold_force,
                v_com: obs.v_com[2].abs(),
                v_res: obs.v_res,
                bilateral,
            };
            self.layer.gate.update(&self.cfg.gate, &x, obs.time);
            obs.gate_open = self.layer.gate.opened_at.is_some();
        }
        let tr = Transition { gate_open: obs.gate_open, pad_height: self.gripper.height(b), sponge_height, bilateral };
        let input = self.control_input();
        if let Some(next) = self.layer.controller.advance(&p, &input, tr) {
            self.layer.phase_water.push((next, obs.m_l));
            obs.phase = Some(next);
        }
        self.layer.obs = obs;
        Ok(&self.layer.obs)
    }

    /// [`Trial::step`] as a recorded run takes it: the observation joins `records` every
    /// `record_every` steps and at the end (`keep_going` sees it first; `false` stops the run
    /// with [`RmiError::State`]), and a run past its time limit is an error.
    pub(crate) fn step_recording<F: FnMut(&Observation) -> bool>(
        &mut self,
        records: &mut Vec<Observation>,
        keep_going: &mut F,
    ) -> Result<()> {
        self.step()?;
        if self.sim.step_count().is_multiple_of(self.cfg.record_every as u64) || self.finished() {
            let r = self.take_record();
            if !keep_going(&r) {
                return Err(RmiError::State(format!("trial interrupted at t = {:.3} s", self.sim.time())));
            }
            records.push(r);
        }
        let limit = self.cfg.time_limit();
        if self.sim.time() > limit {
            return Err(RmiError::State(format!("trial did not finish within its time limit of {limit:.2} s")));
        }
        Ok(())
    }

    /// Sets the squeeze force target (N, in [0, [`FORCE_LIMIT`]]) of a trial whose squeeze has
    /// not yet run a step (it may have just entered it): nothing before depends on it unless
    /// the force targets are perturbed, whose schedule it seeds from the lift on.
    pub(crate) fn set_squeeze_force(&mut self, force: f64) -> Result<()> {
        check_range("squeeze_force", force, 0.0, FORCE_LIMIT, "N")?;
        self.cfg.squeeze_force = force;
        self.layer.controller.squeeze_force = force;
        Ok(())
    }

    /// The latest observation with the pad loads averaged over the steps since the previous
    /// call (the instantaneous loads alternate by a few per cent from step to step); starts
    /// a new averaging interval.
    pub fn take_record(&mut self) -> Observation {
        let mut o = self.layer.obs.clone();
        let ls = std::mem::take(&mut self.layer.load_sum);
        if ls.steps > 0 {
            let n = ls.steps as f64;
            o.f_l = ls.left / n;
            o.f_r = ls.right / n;
            o.f_meas = 0.5 * (o.f_l + o.f_r);
            o.wrist_load = ls.wrist.map(|w| w / n);
        }
        o
    }

    /// Water removed per phase so far (kg), in phase order, including the running phase.
    pub fn water_removed(&self) -> Vec<(String, f64)> {
        // A phase loses what it held at its entry minus what the next one starts with.
        let mut removed = vec![0.0; Phase::ALL.len()];
        let ends = self.layer.phase_water.iter().skip(1).map(|x| x.1).chain([self.layer.obs.m_l]);
        for ((ph, start), end) in self.layer.phase_water.iter().zip(ends) {
            removed[*ph as usize] += start - end;
        }
        Phase::ALL
            .iter()
            .zip(removed)
            .filter(|(p, _)| **p != Phase::Done)
            .map(|(p, w)| (p.name().to_string(), w))
            .collect()
    }

    /// The outcome so far (final once [`Trial::finished`]).
    pub fn outcome(&self, wall_s: f64) -> Outcome {
        let c = &self.layer.controller;
        let reached = |ph: Phase| self.layer.phase_water.iter().any(|(p, _)| *p == ph);
        let total = self.total_water();
        Outcome {
            lift_success: reached(Phase::Squeeze),
            stable_squeeze: self.finished() && c.failure.is_none(),
            failure: c.failure.map(|f| f.name().to_string()),
            gate_opened_at: self.layer.gate.opened_at,
            water_removed: self.water_removed(),
            initial_water: self.layer.initial_water,
            final_water: self.layer.obs.m_l,
            total_water: total,
            sim_time: self.sim.time(),
            steps: self.sim.step_count(),
            wall_s,
            n_fluid: self.sim.particles().n_fluid,
            n_solid: self.sim.particles().n_solid(),
        }
    }

    /// Serialises the whole state (simulation and robot layer) for a bit-identical
    /// continuation.
    ///
    /// Layout: header, bincode payload (config JSON, simulation snapshot, robot layer), then
    /// a 64-bit checksum of header and payload ([`rmi_sph::simulation::seal`]).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = MAGIC.to_vec();
        let body = (self.cfg.to_json(), self.sim.snapshot().to_bytes(), &self.layer);
        out.extend(bincode::serialize(&body).expect("trial state serialises"));
        seal(out)
    }

    /// Restores a state written by [`Trial::to_bytes`] into a new trial. Every failure is a
    /// [`RmiError::State`]: a bad header or checksum, or content that does not fit together
    /// (its config, the snapshot's particles and the robot layer).
    pub fn from_bytes(b: &[u8], threads: Option<usize>) -> Result<Self> {
        if OLD_MAGICS.iter().any(|m| b.len() >= m.len() && &b[..m.len()] == *m) {
            return Err(RmiError::State("trial state of an older format; not readable".into()));
        }
        if b.len() < MAGIC.len() || &b[..MAGIC.len()] != MAGIC {
            return Err(RmiError::State("not an rmi trial state (bad header)".into()));
        }
        let body = unseal(b, "trial state")?;
        let (json, snap, layer): (String, Vec<u8>, Layer) = bincode::deserialize(&body[MAGIC.len()..])
            .map_err(|e| RmiError::State(format!("corrupt trial state: {e}")))?;
        let cfg = TrialConfig::from_json(&json)
            .map_err(|e| RmiError::State(format!("the trial state's config is not valid: {e}")))?;
        let snap = Snapshot::from_bytes(&snap)?;
        if snap.config.to_json() != cfg.sim_config().to_json() {
            return Err(RmiError::State("trial state: the simulation snapshot is not of the trial's config".into()));
        }
        // The state replaces the scene: build it without the soak.
        let mut t = Trial::around(cfg.clone(), Simulation::build(cfg.sim_config(), threads)?)?;
        if layer.memory.particles() != snap.particles.n_solid() {
            return Err(RmiError::State("trial state: contact memory does not match the particles".into()));
        }
        layer.memory.check(snap.bodies.len(), snap.particles.n_fluid).map_err(|e| match e {
            RmiError::State(m) => RmiError::State(format!("trial state: {m}")),
            other => other,
        })?;
        t.sim.restore(snap)?;
        t.sim.update_fields();
        t.layer = layer;
        Ok(t)
    }

    /// Writes the state to `path` atomically.
    pub fn save(&self, path: &std::path::Path) -> Result<()> {
        write_atomic(path, &self.to_bytes())
    }

    /// Reads a state file written by [`Trial::save`].
    pub fn load(path: &std::path::Path, threads: Option<usize>) -> Result<Self> {
        Self::from_bytes(&read_state(path)?, threads)
    }
}

/// A finished trial: recorded rows and the outcome.
#[derive(Clone, Debug)]
pub struct TrialResult {
    /// One observation every `record_every` steps (loads averaged over the interval), from
    /// the initial state to the end.
    pub records: Vec<Observation>,
    /// How it ended.
    pub outcome: Outcome,
}

/// Runs the scripted trial to the end (or to a failure) and records it.
pub fn run_trial(cfg: TrialConfig, threads: Option<usize>) -> Result<TrialResult> {
    run_trial_with(cfg, threads, |_| true)
}

/// [`run_trial`] with a callback after every recorded row; returning `false` stops the
/// trial early with [`RmiError::State`] (used to honour interrupts from Python).
pub fn run_trial_with<F: FnMut(&Observation) -> bool>(
    cfg: TrialConfig,
    threads: Option<usize>,
    mut keep_going: F,
) -> Result<TrialResult> {
    let start = std::time::Instant::now();
    let mut t = Trial::new(cfg, threads)?;
    let mut records = vec![t.take_record()];
    while !t.finished() {
        t.step_recording(&mut records, &mut keep_going)?;
    }
    Ok(TrialResult { outcome: t.outcome(start.elapsed().as_secs_f64()), records })
}
