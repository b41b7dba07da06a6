//! The closed loop's settings, and the names of the further probes' directories they imply.

use crate::{ResearchError, Result};
use fishprobe_learn::PpoConfig;
use fishprobe_sim::params::check;
use fishprobe_sim::OodScore;

fishprobe_sim::documented_params! {
    /// The closed loop's budget and design (defaults: the run in docs/validation.md).
    pub struct OodLoopConfig {
        /// The robot of the narrow recordings (choice: the goal-seeker, which shuttles between
        /// the two evaluation goals and ignores the fish, so the data holds a robot on one
        /// diagonal and a fish that comes and goes).
        pub narrow_controller: String = "scripted:goal-seeker".into(); "-",
        /// Narrow episodes the first model is fitted on (choice: 12).
        pub narrow_episodes: usize = 12; "episodes",
        /// Held-out narrow episodes for early stopping of every fit (choice: 3).
        pub validation_episodes: usize = 3; "episodes",
        /// Episodes recorded under each policy and added to the data (choice: 6: half the
        /// narrow data again).
        pub new_episodes: usize = 6; "episodes",
        /// Rounds of policy training, recording and refitting (choice: 1: train, record, refit once).
        /// In round k > 1 each chain trains a new policy against its own model of round k - 1
        /// (the OOD chain against the model refitted with OOD data, the lead-to-goal chain
        /// against its own), records `new_episodes` more and refits on the narrow data plus
        /// all its chain's recordings: the paper's "iterative model and policy retraining".
        /// The gaps are those of each chain's last model.
        pub rounds: usize = 1; "rounds",
        /// Minutes per recorded episode (choice: 3).
        pub episode_minutes: f32 = 3.0; "min",
        /// PPO preset of both policies (choice: `quick`).
        pub ppo_preset: String = "quick".into(); "-",
        /// Environment steps of each policy (choice: 200,000, the quick preset's).
        pub train_steps: u64 = 200_000; "steps",
        /// Most epochs of each M_ConvNet fit (choice: 15).
        pub fit_max_epochs: usize = 15; "epochs",
        /// The probe that measures each model's gap (choice: `scripted:fetch-and-lead`,
        /// which neither policy is and which interacts with the fish closely).
        pub gap_probe: String = "scripted:fetch-and-lead".into(); "-",
        /// Further probes whose gaps are measured the same way and reported beside the first
        /// (choice: the goal-seeker, whose situations the narrow data holds, and the random
        /// robot, whose situations no policy chose: data where a model is least supported
        /// need not be where one probe looks). The verdict of `loop.md` is given per probe
        /// and over all of them.
        pub more_gap_probes: Vec<String> = vec!["scripted:goal-seeker".into(), "scripted:random".into()]; "-",
        /// Gap episodes per model and for the virtual guppy (choice: 6).
        pub gap_episodes: usize = 6; "episodes",
        /// Minutes per gap episode (choice: 5).
        pub gap_minutes: f32 = 5.0; "min",
        /// Partner range of every fitted model's support (`support.partner_range_cm`; choice:
        /// 0, every partner counts, as the shipped support; 15 makes the OOD policy seek
        /// close interactions, docs/validation.md, "Probes that seek what the data lacks").
        pub support_partner_range_cm: f32 = 0.0; "cm",
        /// What the OOD policy is rewarded by (`task.ood_score`): `support` (choice: the rarity
        /// of the fish's views in the model's training data) or `disagreement` (how much an
        /// ensemble of `ensemble_members` fits of the model disagrees on them; every model
        /// the OOD chain trains against is then fitted as an ensemble). The share of the OOD
        /// policy's views beyond the lead-to-goal policy's p95 is measured in support scores
        /// either way.
        pub ood_score: OodScore = OodScore::Support; "-",
        /// Networks of each ensemble with `ood_score = "disagreement"`, in [2, 16] (choice: 4:
        /// enough for a stable disagreement, each member one more fit).
        pub ensemble_members: usize = 4; "networks",
    }
}

impl OodLoopConfig {
    /// Refuses settings out of their ranges, naming the setting.
    pub fn validate(&self) -> Result<()> {
        for (f, v, hi) in [
            ("narrow_episodes", self.narrow_episodes, 1000),
            ("validation_episodes", self.validation_episodes, 1000),
            ("new_episodes", self.new_episodes, 1000),
            ("rounds", self.rounds, 20),
            ("gap_episodes", self.gap_episodes, 1000),
            ("fit_max_epochs", self.fit_max_epochs, 1000),
        ] {
            if !(1..=hi).contains(&v) {
                return Err(ResearchError::Refused(format!(
                    "ood-loop setting `{f}` = {v}: must lie in [1, {hi}]"
                )));
            }
        }
        if !(1..=1_000_000_000).contains(&self.train_steps) {
            return Err(ResearchError::Refused(format!(
                "ood-loop setting `train_steps` = {}: must lie in [1, 1e9]",
                self.train_steps
            )));
        }
        fishprobe_learn::evaluate::check_minutes("episode_minutes", self.episode_minutes)?;
        fishprobe_learn::evaluate::check_minutes("gap_minutes", self.gap_minutes)?;
        // The support's own bound, checked before any recording rather than at the first fit.
        check::within(
            "",
            "support_partner_range_cm",
            self.support_partner_range_cm,
            0.0,
            check::MAX_LENGTH_CM,
        )
        .map_err(|e| ResearchError::within("ood-loop settings", e))?;
        if !(2..=fishprobe_models::disagreement::MAX_MEMBERS).contains(&self.ensemble_members) {
            return Err(ResearchError::Refused(format!(
                "ood-loop setting `ensemble_members` = {}: must lie in [2, {}]",
                self.ensemble_members,
                fishprobe_models::disagreement::MAX_MEMBERS
            )));
        }
        if self.more_gap_probes.len() > 8 {
            return Err(ResearchError::Refused(format!(
                "ood-loop setting `more_gap_probes`: at most 8 probes, got {}",
                self.more_gap_probes.len()
            )));
        }
        let mut dirs = vec![probe_dir_name(&self.gap_probe)];
        for p in &self.more_gap_probes {
            let d = probe_dir_name(p);
            if dirs.contains(&d) {
                return Err(ResearchError::Refused(format!(
                    "ood-loop setting `more_gap_probes`: `{p}` is listed twice (or as `gap_probe`)"
                )));
            }
            dirs.push(d);
        }
        for p in std::iter::once(&self.gap_probe).chain(&self.more_gap_probes) {
            fishprobe_learn::controller(p, false).map_err(|e| {
                ResearchError::within(format!("ood-loop settings: gap probe `{p}`"), e)
            })?;
        }
        if PpoConfig::preset(&self.ppo_preset).is_none() {
            return Err(ResearchError::Refused(format!(
                "ood-loop setting `ppo_preset` = {}: not a preset",
                self.ppo_preset
            )));
        }
        Ok(())
    }
}

/// The directory of a further probe's gap trials under `gap/`: `probe-` and its name with
/// every character but letters, digits and `-` made a `-` (so a policy directory's path makes
/// a name too, and none is the first probe's `guppy`, `narrow`, ...).
pub(super) fn probe_dir_name(probe: &str) -> String {
    let s: String = probe
        .chars()
        .take(80)
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '-'
            }
        })
        .collect();
    format!("probe-{s}")
}
