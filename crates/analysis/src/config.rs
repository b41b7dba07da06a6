//! The analysis settings: SPEC §8's published values as defaults.

use fishprobe_sim::params::{check, ConfigError};

fishprobe_sim::documented_params! {
    /// How the study is analysed.
    pub struct AnalysisConfig {
        /// Sim trials per policy in the sim-to-real comparison: the first N files by name of
        /// `<P>__<P>` (paper: 18; the same directory may also hold the 50 sim-to-sim episodes).
        pub sim_trials: usize = 18; "trials",
        /// Percentile-bootstrap replicates for the sim-to-real goal gap (paper: 5000).
        pub bootstrap_reps: usize = 5000; "replicates",
        /// Permutations of the one-sided permutation tests (paper: 100,000).
        pub permutations: usize = 100_000; "permutations",
        /// Two-way cluster-bootstrap replicates of the per-metric gaps (paper: 5000).
        pub cluster_bootstrap_reps: usize = 5000; "replicates",
        /// Bootstrap replicates per sim-to-sim cell (paper: 5000).
        pub sim_to_sim_reps: usize = 5000; "replicates",
        /// Episode-bootstrap replicates of the stability ratio (paper: 2000).
        pub stability_bootstrap_reps: usize = 2000; "replicates",
        /// Permutations of the stability ratio (paper: 5000).
        pub stability_permutations: usize = 5000; "permutations",
        /// Confidence level of every interval (paper: 95 %).
        pub ci_level: f64 = 0.95; "1",
        /// Goal radius used when goal events must be recomputed from a track (paper: 5 cm).
        pub goal_radius_cm: f32 = 5.0; "cm",
        /// Evaluation goals, in order, for recomputing goal events (paper: opposite corners;
        /// choice: (-20, -20) first).
        pub goals: [[f32; 2]; 2] = [[-20.0, -20.0], [20.0, 20.0]]; "cm",
        /// Minutes of control analysed for goals per minute (paper: 15 bins of 1 min).
        pub minutes: usize = 15; "min",
        /// Approach assay: the goal's position when a file does not record it (choice:
        /// (20, -20), see SPEC §8).
        pub approach_goal: [f32; 2] = [20.0, -20.0]; "cm",
        /// Probe competence: a policy reaching fewer goals on its own model than this
        /// fraction of the best scripted controller's is flagged as a weak probe, whose
        /// strategy reflects the optimiser as much as the model (choice: 0.8).
        pub competence_threshold: f64 = 0.8; "1",
        /// Approach assay, per training seed: a policy goes to the still fish when it comes
        /// at least this close to it (choice, a reading of the paper's pattern:
        /// π_Zone came within 4 cm, π_Force within 0.35 cm, π_Follow not at all; 10 cm) ...
        pub approach_closest_cm: f64 = 10.0; "cm",
        /// ... and is nearer the fish than the goal in at least this fraction of the frames
        /// (choice: 0.1; the paper's π_Zone 22.3 %, π_Force 56.1 %, π_ConvNet 4.6 %).
        pub approach_nearer_share: f64 = 0.1; "1",
        /// A fish this close to the robot counts as within its reach: for the group metric
        /// `fish_near_robot`, and for the time a probe takes to reach its fish (probe
        /// competence, `time_to_reach_s`) (choice: 15 cm, M_Force's interaction range and near
        /// M_Zone's outer attraction radius of 18 cm).
        pub robot_reach_cm: f32 = 15.0; "cm",
        /// A fish slower than this is paused, for the per-trial paused fraction of the
        /// between-trial spread (the data README's threshold, as in `compare-offline`:
        /// 0.5 cm/s).
        pub pause_cm_s: f32 = 0.5; "cm/s",
        /// A reality-arm trial whose control phase is longer or shorter than the arm's
        /// (median) by more than this is left out and named: goals count over the whole
        /// control phase, so a trial ended early is not one more trial of the protocol
        /// (choice: 2 s, a command period of slack either way). An arm of foreign
        /// recordings (no task record) has no fixed control length and is not checked.
        pub control_length_tolerance_s: f64 = 2.0; "s",
    }
}

impl AnalysisConfig {
    /// Most replicates, permutations, trials or minutes any count may be (10^7: 100 times the
    /// paper's 100,000 permutations).
    pub const MAX_RESAMPLES: usize = 10_000_000;

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (name, v) in [
            ("sim_trials", self.sim_trials),
            ("bootstrap_reps", self.bootstrap_reps),
            ("permutations", self.permutations),
            ("cluster_bootstrap_reps", self.cluster_bootstrap_reps),
            ("sim_to_sim_reps", self.sim_to_sim_reps),
            ("stability_bootstrap_reps", self.stability_bootstrap_reps),
            ("stability_permutations", self.stability_permutations),
            ("minutes", self.minutes),
        ] {
            if v == 0 {
                return Err(ConfigError::new("analysis", name, 0, "must be at least 1"));
            }
            // Bootstrap replicates are held in memory (8 bytes each) and every resample
            // costs time: far above the paper's 5,000 and 100,000 is a typo, not a wish.
            if v > Self::MAX_RESAMPLES {
                return Err(ConfigError::new(
                    "analysis",
                    name,
                    v,
                    &format!("must be at most {}", Self::MAX_RESAMPLES),
                ));
            }
        }
        // The f64 settings: (name, value, whether it is in range, the range in words).
        for (name, v, ok, why) in [
            (
                "ci_level",
                self.ci_level,
                self.ci_level > 0.0 && self.ci_level < 1.0,
                "must lie in (0, 1)",
            ),
            (
                "approach_closest_cm",
                self.approach_closest_cm,
                self.approach_closest_cm > 0.0 && self.approach_closest_cm.is_finite(),
                "must be a positive distance",
            ),
            (
                "competence_threshold",
                self.competence_threshold,
                self.competence_threshold >= 0.0 && self.competence_threshold.is_finite(),
                "must be a non-negative fraction of the best scripted controller's goals",
            ),
            (
                "approach_nearer_share",
                self.approach_nearer_share,
                (0.0..=1.0).contains(&self.approach_nearer_share),
                "must lie in [0, 1]",
            ),
        ] {
            if !ok {
                return Err(ConfigError::new("analysis", name, v, why));
            }
        }
        for (f, v) in [
            ("goal_radius_cm", self.goal_radius_cm),
            ("robot_reach_cm", self.robot_reach_cm),
        ] {
            check::positive_at_most("analysis", f, v, check::MAX_LENGTH_CM)?;
        }
        let tol = self.control_length_tolerance_s;
        if !(tol.is_finite() && (0.0..=f64::from(check::MAX_DURATION_S)).contains(&tol)) {
            return Err(ConfigError::new(
                "analysis",
                "control_length_tolerance_s",
                check::shown(tol),
                &format!("must lie in [0, {}] s", check::MAX_DURATION_S),
            ));
        }
        check::within(
            "analysis",
            "pause_cm_s",
            self.pause_cm_s,
            0.0,
            check::MAX_SPEED_CM_S,
        )?;
        if self.approach_closest_cm > f64::from(check::MAX_LENGTH_CM) {
            return Err(ConfigError::new(
                "analysis",
                "approach_closest_cm",
                check::shown(self.approach_closest_cm),
                &format!("must be at most {} cm", check::MAX_LENGTH_CM),
            ));
        }
        Ok(())
    }

    /// This config with some settings replaced: `table` maps field names to values (a study
    /// file's `[analysis]` table, `fishprobe analyze --settings FILE`), applied one by one so
    /// that an unknown name or a value of the wrong type is refused by name; the result is
    /// checked ([`AnalysisConfig::validate`]).
    pub fn with_overrides(
        &self,
        table: &serde_json::Map<String, serde_json::Value>,
    ) -> Result<Self, ConfigError> {
        let cur = fishprobe_sim::params::replace_by_name(self, "analysis", table)?;
        cur.validate()?;
        Ok(cur)
    }

    /// Small replicate counts for quick looks and tests (the statistics are the same).
    pub fn quick() -> Self {
        Self {
            bootstrap_reps: 500,
            permutations: 2000,
            cluster_bootstrap_reps: 300,
            sim_to_sim_reps: 500,
            stability_bootstrap_reps: 300,
            stability_permutations: 500,
            ..Self::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn approach_thresholds_out_of_range_are_refused_by_name() {
        assert!(AnalysisConfig::default().validate().is_ok());
        for (cfg, field) in [
            (
                AnalysisConfig {
                    approach_closest_cm: 0.0,
                    ..AnalysisConfig::default()
                },
                "approach_closest_cm",
            ),
            (
                AnalysisConfig {
                    approach_closest_cm: f64::NAN,
                    ..AnalysisConfig::default()
                },
                "approach_closest_cm",
            ),
            (
                AnalysisConfig {
                    approach_nearer_share: 1.5,
                    ..AnalysisConfig::default()
                },
                "approach_nearer_share",
            ),
            (
                AnalysisConfig {
                    approach_nearer_share: f64::NAN,
                    ..AnalysisConfig::default()
                },
                "approach_nearer_share",
            ),
        ] {
            let e = cfg.validate().err().map(|e| e.to_string());
            assert!(
                e.as_deref().is_some_and(|e| e.contains(field)),
                "{field}: {e:?}"
            );
        }
    }

    #[test]
    fn overrides_replace_named_settings_and_refuse_unknown_or_mistyped_ones() {
        let table = |json: &str| match serde_json::from_str(json) {
            Ok(serde_json::Value::Object(o)) => o,
            other => panic!("{other:?}"),
        };
        let base = AnalysisConfig::quick();
        let c = base
            .with_overrides(&table(
                r#"{"approach_closest_cm": 4.0, "competence_threshold": 0.9}"#,
            ))
            .expect("valid overrides");
        assert_eq!(c.approach_closest_cm, 4.0);
        assert_eq!(c.competence_threshold, 0.9);
        // Everything else is the base's, not the defaults'.
        assert_eq!(c.permutations, base.permutations);
        assert_eq!(c.approach_nearer_share, base.approach_nearer_share);
        for (json, field) in [
            (r#"{"approach_closest": 4.0}"#, "approach_closest"),
            (r#"{"permutations": "many"}"#, "permutations"),
            (r#"{"approach_nearer_share": 2.0}"#, "approach_nearer_share"),
            (r#"{"permutations": 0}"#, "permutations"),
            (r#"{"ci_level": null}"#, "ci_level"),
        ] {
            let e = base
                .with_overrides(&table(json))
                .err()
                .map(|e| e.to_string());
            assert!(
                e.as_deref().is_some_and(|e| e.contains(field)),
                "{json}: {e:?}"
            );
        }
        // TOML's nan becomes null on its way to JSON: refused as not finite, not as mistyped.
        let nan: toml::Table = toml::from_str("ci_level = nan").expect("toml");
        let nan = match serde_json::to_value(nan) {
            Ok(serde_json::Value::Object(o)) => o,
            other => panic!("{other:?}"),
        };
        let e = base.with_overrides(&nan).err().map(|e| e.to_string());
        assert!(
            e.as_deref().is_some_and(|e| e.contains("analysis.ci_level")
                && e.contains("finite")
                && !e.contains("wrong type")),
            "{e:?}"
        );
    }
}
