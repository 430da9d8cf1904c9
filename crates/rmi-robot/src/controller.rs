//! Hybrid velocity/force regulation of the gripper (paper Eq. 5) and the phase sequence of a
//! grasp-lift-squeeze trial.
//!
//! The pads close at a prescribed speed until the load has stayed above a contact threshold
//! for `k_contact` steps; from then on the closing speed is
//! `v_cmd = clip(k_F (F_target - F_meas), -v_open, v_close)` with a target that ramps
//! smoothly (C1 smoothstep) from the contact load to the holding force, holds, and later
//! ramps to the squeeze force. The guards on the force limit and the minimum width act in
//! every phase, also when a caller drives the gripper with its own `u_t = [F_target, v_cmd]`.

use crate::gripper::FORCE_LIMIT;
use crate::perturbation::SetpointPerturbation;
use rmi_sph::config::check_range;
use rmi_sph::{Result, RmiError};
use serde::{Deserialize, Serialize};

/// Controller phases, in the order a trial visits them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub enum Phase {
    /// Pads open; the soaked sponge settles on the floor.
    Settle,
    /// Pads approach at the closing speed.
    Close,
    /// Target ramps from the contact load to the holding force.
    Ramp,
    /// Holding force kept; the lift gate is evaluated.
    Hold,
    /// Both pads move up by the lift height.
    Lift,
    /// The sponge is held in the air at the holding force.
    Waiting,
    /// Target ramps to the squeeze force and holds it.
    Squeeze,
    /// The trial is over (completed or failed).
    Done,
}

impl Phase {
    /// All phases in order.
    pub const ALL: [Phase; 8] = [
        Phase::Settle,
        Phase::Close,
        Phase::Ramp,
        Phase::Hold,
        Phase::Lift,
        Phase::Waiting,
        Phase::Squeeze,
        Phase::Done,
    ];

    /// Stable lower-case name (used in stored data).
    pub fn name(self) -> &'static str {
        match self {
            Phase::Settle => "settle",
            Phase::Close => "close",
            Phase::Ramp => "ramp",
            Phase::Hold => "hold",
            Phase::Lift => "lift",
            Phase::Waiting => "waiting",
            Phase::Squeeze => "squeeze",
            Phase::Done => "done",
        }
    }
}

/// Why a trial ended early.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Failure {
    /// The pads reached the minimum width without a sustained contact load.
    NoContact,
    /// The lift gate did not open within the timeout after the hold.
    GateTimeout,
    /// The sponge fell relative to the pads by more than the drop distance.
    Dropped,
    /// Bilateral contact was lost while the sponge was held in the air.
    SlippedOut,
}

impl Failure {
    /// Stable lower-case name (used in stored data).
    pub fn name(self) -> &'static str {
        match self {
            Failure::NoContact => "no_contact",
            Failure::GateTimeout => "gate_timeout",
            Failure::Dropped => "dropped",
            Failure::SlippedOut => "slipped_out",
        }
    }
}

/// Timing, gains and guards (SI: s, m/s, N, m).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ControllerParams {
    /// Time the sponge settles before the pads move (s).
    pub settle_time: f64,
    /// Closing speed of each pad before contact (m/s).
    pub close_speed: f64,
    /// Load threshold that counts as contact (N).
    pub contact_force: f64,
    /// Consecutive steps above the threshold before force regulation starts.
    pub k_contact: u32,
    /// Duration of the ramp to the holding force (s).
    pub ramp_time: f64,
    /// Minimum hold before the gate may release the lift (s).
    pub hold_time: f64,
    /// Longest wait for the gate after the hold (s); then the trial fails.
    pub gate_timeout: f64,
    /// Force gain k_F (m/(s N)).
    pub k_f: f64,
    /// Largest opening speed per pad (m/s).
    pub v_open: f64,
    /// Largest closing speed per pad (m/s).
    pub v_close: f64,
    /// Smallest pad-to-pad width (m); closing stops there.
    pub min_width: f64,
    /// Lift speed (m/s).
    pub lift_speed: f64,
    /// Time over which the lift speed ramps up (s): a real arm cannot jump to speed, and a
    /// jump would demand an unbounded friction force.
    pub lift_accel_time: f64,
    /// Lift distance (m).
    pub lift_height: f64,
    /// Time held in the air before the squeeze (s).
    pub wait_time: f64,
    /// Duration of the ramp to the squeeze force (s).
    pub squeeze_ramp_time: f64,
    /// Duration of the squeeze hold (s).
    pub squeeze_hold_time: f64,
    /// Fall of the sponge relative to the pads that counts as a drop (m).
    pub drop_distance: f64,
    /// Steps without bilateral contact in the air that count as slipping out.
    pub k_lost: u32,
    /// Seeded force targets from the lift on, instead of the scripted ones (off by default).
    pub perturbation: SetpointPerturbation,
}

impl Default for ControllerParams {
    fn default() -> Self {
        ControllerParams {
            settle_time: 0.2,
            close_speed: 0.05,
            contact_force: 1.0,
            k_contact: 10,
            ramp_time: 0.5,
            hold_time: 0.4,
            gate_timeout: 1.0,
            k_f: 2e-3,
            v_open: 0.05,
            v_close: 0.05,
            min_width: 0.01,
            lift_speed: 0.1,
            lift_accel_time: 0.1,
            lift_height: 0.04,
            wait_time: 0.3,
            squeeze_ramp_time: 0.5,
            squeeze_hold_time: 0.5,
            drop_distance: 0.015,
            k_lost: 20,
            perturbation: SetpointPerturbation::default(),
        }
    }
}

impl ControllerParams {
    /// Validates every field; `p` is the dotted path used in error messages.
    pub fn validate(&self, p: &str) -> Result<()> {
        let r = |f: &str, v: f64, lo: f64, hi: f64, u: &str| check_range(&format!("{p}.{f}"), v, lo, hi, u);
        r("settle_time", self.settle_time, 0.0, 100.0, "s")?;
        r("close_speed", self.close_speed, 1e-4, 1.0, "m/s")?;
        r("contact_force", self.contact_force, 0.0, FORCE_LIMIT, "N")?;
        r("ramp_time", self.ramp_time, 0.0, 100.0, "s")?;
        r("hold_time", self.hold_time, 0.0, 100.0, "s")?;
        r("gate_timeout", self.gate_timeout, 0.0, 100.0, "s")?;
        r("k_f", self.k_f, 0.0, 1.0, "m/(s N)")?;
        r("v_open", self.v_open, 0.0, 1.0, "m/s")?;
        r("v_close", self.v_close, 0.0, 1.0, "m/s")?;
        r("min_width", self.min_width, 0.0, 1.0, "m")?;
        r("lift_speed", self.lift_speed, 1e-4, 1.0, "m/s")?;
        r("lift_accel_time", self.lift_accel_time, 0.0, 10.0, "s")?;
        r("lift_height", self.lift_height, 0.0, 1.0, "m")?;
        r("wait_time", self.wait_time, 0.0, 100.0, "s")?;
        r("squeeze_ramp_time", self.squeeze_ramp_time, 0.0, 100.0, "s")?;
        r("squeeze_hold_time", self.squeeze_hold_time, 0.0, 100.0, "s")?;
        r("drop_distance", self.drop_distance, 1e-4, 1.0, "m")?;
        if self.k_contact == 0 || self.k_contact > 100_000 {
            return Err(RmiError::config(format!("{p}.k_contact"), self.k_contact, "an integer in [1, 100000]"));
        }
        if self.k_lost == 0 || self.k_lost > 100_000 {
            return Err(RmiError::config(format!("{p}.k_lost"), self.k_lost, "an integer in [1, 100000]"));
        }
        self.perturbation.validate(&format!("{p}.perturbation"))
    }
}

/// An action u_t supplied from outside: force target (N) and, optionally, the closing speed
/// per pad (m/s, positive closes). Without a speed the force regulation of Eq. 5b runs.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Action {
    /// Force target F_target (N), clipped to [0, 400].
    pub force_target: f64,
    /// Closing speed v_cmd (m/s); `None` regulates toward the target.
    pub velocity: Option<f64>,
}

impl Action {
    /// Checks that the values are finite and in range.
    pub fn validate(&self) -> Result<()> {
        check_range("force_target", self.force_target, 0.0, FORCE_LIMIT, "N")?;
        if let Some(v) = self.velocity {
            check_range("velocity_command", v, -1.0, 1.0, "m/s")?;
        }
        Ok(())
    }
}

/// What the controller sees each step.
#[derive(Clone, Copy, Debug)]
pub struct ControlInput {
    /// Simulated time (s).
    pub time: f64,
    /// Filtered realised grip load (N).
    pub force: f64,
    /// Pad-to-pad width (m).
    pub width: f64,
}

/// The command for the next step: u_t and the common lift speed (m/s).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Command {
    /// F_target (N).
    pub force_target: f64,
    /// v_cmd, closing speed per pad (m/s).
    pub v_cmd: f64,
    /// Lift speed of both pads (m/s).
    pub lift_speed: f64,
}

/// C1 smoothstep from 0 to 1 over s in [0, 1].
pub fn smoothstep(s: f64) -> f64 {
    let s = s.clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

/// Eq. 5b with the guards: the regulated closing speed, stopped at the minimum width and
/// reversed above the force limit.
pub fn regulate(p: &ControllerParams, target: f64, input: &ControlInput) -> f64 {
    guard(p, p.k_f * (target - input.force), input)
}

/// The speed limits and guards, applied to any closing speed.
pub fn guard(p: &ControllerParams, v: f64, input: &ControlInput) -> f64 {
    let mut v = v.clamp(-p.v_open, p.v_close);
    if input.force >= FORCE_LIMIT {
        v = -p.v_open;
    }
    if input.width <= p.min_width {
        v = v.min(0.0);
    }
    v
}

/// Controller state; serialisable so that a saved robot continues identically.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Controller {
    /// Holding force (N).
    pub hold_force: f64,
    /// Squeeze force (N).
    pub squeeze_force: f64,
    /// Current phase.
    pub phase: Phase,
    /// Time the phase began (s).
    pub phase_start: f64,
    /// Load at the switch to force regulation (N).
    pub contact_load: f64,
    /// Consecutive steps above the contact threshold.
    pub contact_steps: u32,
    /// Consecutive steps without bilateral contact in the air.
    pub lost_steps: u32,
    /// Pad height when the lift began (m).
    pub lift_start: Option<f64>,
    /// Sponge height relative to the pads when the lift began (m).
    pub lift_reference: Option<f64>,
    /// External action, applied until replaced or cleared.
    pub external: Option<Action>,
    /// Why the trial ended early.
    pub failure: Option<Failure>,
    /// Last command.
    pub last: Command,
}

impl Controller {
    /// A controller in the settle phase for the given holding and squeeze forces (N).
    pub fn new(hold_force: f64, squeeze_force: f64) -> Self {
        Controller {
            hold_force: hold_force.clamp(0.0, FORCE_LIMIT),
            squeeze_force: squeeze_force.clamp(0.0, FORCE_LIMIT),
            phase: Phase::Settle,
            phase_start: 0.0,
            contact_load: 0.0,
            contact_steps: 0,
            lost_steps: 0,
            lift_start: None,
            lift_reference: None,
            external: None,
            failure: None,
            last: Command::default(),
        }
    }

    /// The scripted force target of the current phase at `time` (N): from the lift on, the
    /// perturbed schedule when `p.perturbation` is enabled.
    pub fn scripted_target(&self, p: &ControllerParams, time: f64) -> f64 {
        let perturbed = matches!(self.phase, Phase::Lift | Phase::Waiting | Phase::Squeeze);
        if perturbed && p.perturbation.enabled {
            return p.perturbation.target(self.hold_force, self.squeeze_force, time);
        }
        let s = |dur: f64| if dur > 0.0 { smoothstep((time - self.phase_start) / dur) } else { 1.0 };
        match self.phase {
            Phase::Settle | Phase::Close => 0.0,
            Phase::Ramp => self.contact_load + (self.hold_force - self.contact_load) * s(p.ramp_time),
            Phase::Hold | Phase::Lift | Phase::Waiting => self.hold_force,
            Phase::Squeeze => self.hold_force + (self.squeeze_force - self.hold_force) * s(p.squeeze_ramp_time),
            Phase::Done => self.last.force_target,
        }
    }

    /// The command for the next step (scripted, or the external action when one is set).
    pub fn command(&mut self, p: &ControllerParams, x: &ControlInput) -> Command {
        let lift_speed = if self.phase == Phase::Lift {
            let ramp =
                if p.lift_accel_time > 0.0 { smoothstep((x.time - self.phase_start) / p.lift_accel_time) } else { 1.0 };
            p.lift_speed * ramp.max(0.05)
        } else {
            0.0
        };
        let cmd = match (self.phase, self.external) {
            (Phase::Done, _) => Command { force_target: self.last.force_target, v_cmd: 0.0, lift_speed: 0.0 },
            (_, Some(a)) => {
                let target = a.force_target.clamp(0.0, FORCE_LIMIT);
                let v = match a.velocity {
                    Some(v) => guard(p, v, x),
                    None => regulate(p, target, x),
                };
                Command { force_target: target, v_cmd: v, lift_speed }
            }
            (Phase::Settle, None) => Command::default(),
            (Phase::Close, None) => Command { force_target: 0.0, v_cmd: guard(p, p.close_speed, x), lift_speed },
            (_, None) => {
                let target = self.scripted_target(p, x.time).clamp(0.0, FORCE_LIMIT);
                Command { force_target: target, v_cmd: regulate(p, target, x), lift_speed }
            }
        };
        self.last = cmd;
        cmd
    }

    fn enter(&mut self, phase: Phase, time: f64) {
        self.phase = phase;
        self.phase_start = time;
    }

    fn fail(&mut self, f: Failure, time: f64) {
        self.failure = Some(f);
        self.enter(Phase::Done, time);
    }

    /// Phase transitions after a step. `gate_open` is the gate's state, `pad_height` the pads'
    /// height (m), `sponge_height` the sponge's centre of mass height (m), `bilateral`
    /// whether both pads touch it.
    pub fn advance(&mut self, p: &ControllerParams, x: &ControlInput, t: Transition) -> Option<Phase> {
        let elapsed = x.time - self.phase_start + 1e-12;
        let before = self.phase;
        match self.phase {
            Phase::Settle if elapsed >= p.settle_time => self.enter(Phase::Close, x.time),
            Phase::Close => {
                if x.force >= p.contact_force {
                    self.contact_steps += 1;
                } else {
                    self.contact_steps = 0;
                }
                if self.contact_steps >= p.k_contact {
                    self.contact_load = x.force;
                    self.enter(Phase::Ramp, x.time);
                } else if x.width <= p.min_width {
                    self.fail(Failure::NoContact, x.time);
                }
            }
            Phase::Ramp if elapsed >= p.ramp_time => self.enter(Phase::Hold, x.time),
            Phase::Hold if elapsed >= p.hold_time => {
                if t.gate_open {
                    self.lift_start = Some(t.pad_height);
                    self.lift_reference = Some(t.sponge_height - t.pad_height);
                    self.enter(Phase::Lift, x.time);
                } else if elapsed >= p.hold_time + p.gate_timeout {
                    self.fail(Failure::GateTimeout, x.time);
                }
            }
            Phase::Lift | Phase::Waiting | Phase::Squeeze => {
                let reference = self.lift_reference.unwrap_or(t.sponge_height - t.pad_height);
                if t.sponge_height - t.pad_height < reference - p.drop_distance {
                    self.fail(Failure::Dropped, x.time);
                    return Some(Phase::Done);
                }
                self.lost_steps = if t.bilateral { 0 } else { self.lost_steps + 1 };
                if self.lost_steps >= p.k_lost {
                    self.fail(Failure::SlippedOut, x.time);
                    return Some(Phase::Done);
                }
                let lifted = t.pad_height - self.lift_start.unwrap_or(t.pad_height);
                match self.phase {
                    Phase::Lift if lifted >= p.lift_height - 1e-12 => self.enter(Phase::Waiting, x.time),
                    Phase::Waiting if elapsed >= p.wait_time => self.enter(Phase::Squeeze, x.time),
                    Phase::Squeeze if elapsed >= p.squeeze_ramp_time + p.squeeze_hold_time => {
                        self.enter(Phase::Done, x.time)
                    }
                    _ => {}
                }
            }
            _ => {}
        }
        (self.phase != before).then_some(self.phase)
    }
}

/// Measurements the phase transitions need.
#[derive(Clone, Copy, Debug)]
pub struct Transition {
    /// The lift gate is open.
    pub gate_open: bool,
    /// Height of the pads' centre (m).
    pub pad_height: f64,
    /// Height of the sponge's centre of mass (m).
    pub sponge_height: f64,
    /// Both pads touch the sponge.
    pub bilateral: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(time: f64, force: f64, width: f64) -> ControlInput {
        ControlInput { time, force, width }
    }

    const T: Transition = Transition { gate_open: false, pad_height: 0.1, sponge_height: 0.1, bilateral: true };

    #[test]
    fn regulation_is_clipped_and_signed() {
        let p = ControllerParams::default();
        assert!((regulate(&p, 10.0, &input(0.0, 9.0, 0.1)) - p.k_f).abs() < 1e-15);
        assert_eq!(regulate(&p, 300.0, &input(0.0, 0.0, 0.1)), p.v_close);
        assert_eq!(regulate(&p, 0.0, &input(0.0, 300.0, 0.1)), -p.v_open);
    }

    #[test]
    fn guards_act_on_external_commands() {
        let p = ControllerParams::default();
        // Above the force limit the pads open whatever the command.
        assert_eq!(guard(&p, 0.05, &input(0.0, 401.0, 0.1)), -p.v_open);
        // At the minimum width they do not close further but may open.
        assert_eq!(guard(&p, 0.05, &input(0.0, 10.0, p.min_width)), 0.0);
        assert_eq!(guard(&p, -0.01, &input(0.0, 10.0, p.min_width)), -0.01);
        let mut c = Controller::new(50.0, 100.0);
        c.phase = Phase::Hold;
        c.external = Some(Action { force_target: 1e4, velocity: Some(0.05) });
        let cmd = c.command(&p, &input(1.0, 500.0, 0.1));
        assert_eq!(cmd.force_target, FORCE_LIMIT);
        assert_eq!(cmd.v_cmd, -p.v_open);
    }

    #[test]
    fn switches_to_force_regulation_after_k_contact_steps() {
        let p = ControllerParams { k_contact: 3, settle_time: 0.0, ..Default::default() };
        let mut c = Controller::new(50.0, 100.0);
        assert_eq!(c.advance(&p, &input(0.0, 0.0, 0.1), T), Some(Phase::Close));
        for k in 0..2 {
            assert_eq!(c.advance(&p, &input(0.001 * k as f64, 2.0, 0.1), T), None);
        }
        // A dip below the threshold restarts the count.
        c.advance(&p, &input(0.003, 0.5, 0.1), T);
        for k in 0..2 {
            assert_eq!(c.advance(&p, &input(0.004 + 0.001 * k as f64, 2.0, 0.1), T), None);
        }
        assert_eq!(c.advance(&p, &input(0.006, 2.5, 0.1), T), Some(Phase::Ramp));
        assert_eq!(c.contact_load, 2.5);
        // The ramp starts at the contact load and ends at the holding force, smoothly.
        assert!((c.scripted_target(&p, 0.006) - 2.5).abs() < 1e-12);
        assert!((c.scripted_target(&p, 0.006 + p.ramp_time) - 50.0).abs() < 1e-12);
        let mid = c.scripted_target(&p, 0.006 + 0.5 * p.ramp_time);
        assert!((mid - 26.25).abs() < 1e-9);
    }

    #[test]
    fn lift_waits_for_the_gate_and_times_out() {
        let p = ControllerParams::default();
        let mut c = Controller::new(50.0, 100.0);
        c.enter(Phase::Hold, 1.0);
        assert_eq!(c.advance(&p, &input(1.0 + p.hold_time + 0.01, 50.0, 0.1), T), None);
        let open = Transition { gate_open: true, ..T };
        assert_eq!(c.advance(&p, &input(1.0 + p.hold_time + 0.02, 50.0, 0.1), open), Some(Phase::Lift));
        let mut c = Controller::new(50.0, 100.0);
        c.enter(Phase::Hold, 1.0);
        let late = 1.0 + p.hold_time + p.gate_timeout + 0.001;
        assert_eq!(c.advance(&p, &input(late, 50.0, 0.1), T), Some(Phase::Done));
        assert_eq!(c.failure, Some(Failure::GateTimeout));
    }

    #[test]
    fn a_drop_relative_to_the_pads_fails_the_lift() {
        let p = ControllerParams::default();
        let mut c = Controller::new(50.0, 100.0);
        c.enter(Phase::Hold, 0.0);
        let open = Transition { gate_open: true, ..T };
        c.advance(&p, &input(p.hold_time + 0.001, 50.0, 0.1), open);
        assert_eq!(c.phase, Phase::Lift);
        let fallen = Transition { pad_height: 0.13, sponge_height: 0.11, ..open };
        assert_eq!(c.advance(&p, &input(1.0, 50.0, 0.1), fallen), Some(Phase::Done));
        assert_eq!(c.failure, Some(Failure::Dropped));
    }
}
