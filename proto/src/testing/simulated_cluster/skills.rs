//! The simulated skills: what a skill that starts does (`SkillModel`, by default the `motion` skill's parameters),
//! and the simulation's randomness.

use crate::cluster::layout::SkillBinding;
use crate::front::pragma::Param;
use crate::types::Value;

/// A skill that starts in the simulated run, for the `SkillModel` to decide what it does.
pub struct SkillStart<'a> {
    pub agent: &'a str,
    pub action: &'a str,
    pub binding: &'a SkillBinding,
    /// A random number from the run's seed, for durations within a range and the like.
    pub random: u64,
}

/// What a simulated skill does.
#[derive(Clone, Debug, PartialEq)]
pub enum SimSkill {
    /// It ends `after_ms` after it started, with `result`, having first written `writes` (the index of one of
    /// its binding's `outputs`, and the value).
    Finish { after_ms: u64, result: Result<(), String>, writes: Vec<(usize, Value)> },
    /// It never ends on its own: only its action's Q falling stops it.
    Hang,
}

/// xorshift64*: the simulation's randomness, deterministic from a seed. `mix` keeps the streams of one seed
/// apart (the network's, the faults' timing, an agent's skills).
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64, mix: u64) -> Rng {
        Rng(seed.wrapping_mul(mix) | 1)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
}

/// The stream of the simulated network and skills.
pub const NETWORK_MIX: u64 = 0x9E37_79B9_7F4A_7C15;

/// What the `motion` skill does with `random` drawn for it: it ends after its `ms` parameter, failing with
/// probability `fault_rate` (the part of `random` that durations do not use decides).
pub fn motion(binding: &SkillBinding, random: u64) -> SimSkill {
    SimSkill::Finish { after_ms: motion_ms(binding), result: motion_result(binding, random), writes: Vec::new() }
}

/// How long `motion` takes: its `ms` parameter.
pub fn motion_ms(binding: &SkillBinding) -> u64 {
    binding.params.get("ms").and_then(Param::as_f64).unwrap_or(0.0).max(0.0) as u64
}

/// The outcome `motion` draws: a fault with probability `fault_rate`.
pub fn motion_result(binding: &SkillBinding, random: u64) -> Result<(), String> {
    let rate = binding.params.get("fault_rate").and_then(Param::as_f64).unwrap_or(0.0);
    if (((random >> 32) % 1_000_000) as f64 / 1_000_000.0) < rate {
        Err("simulated fault".to_string())
    } else {
        Ok(())
    }
}

/// Decides what each skill that starts does.
pub type SkillModel = Box<dyn FnMut(SkillStart<'_>) -> SimSkill + Send>;
