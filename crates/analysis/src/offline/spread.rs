//! How much recordings differ from one another, real against each model: per statistic of
//! [`RECORDING_STATS`], the per-recording values of the real recordings and of each model's
//! simulated ones; the s.d. ratio model / real with its bootstrap interval, the 1-Wasserstein
//! distance between the per-recording values and the Brown–Forsythe test
//! ([`crate::spread::spread_entry`], as `analyze` measures trials); the real data's own
//! split-half distance, the floor that sampling alone gives; and the Spearman correlations
//! between the statistics across recordings, real beside each model.

use super::metrics::{RecordingValues, RECORDING_STATS};
use super::OfflineConfig;
use crate::results::{nan, SpreadEntry};
use fishprobe_sim::{stream, SimRng};
use fishprobe_stats as st;
use rand::RngExt;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The spread section of one comparison (pairs, or the open-loop robot recordings).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct OfflineSpread {
    /// The statistics' ids, in order.
    pub statistics: Vec<String>,
    /// "real" or a model → statistic → each recording's value, in recording order (null: no
    /// value; a model's value for a recording is that of its simulation of the recording;
    /// with `replicates` R, a model has R n values, simulation i of recording i mod n).
    pub values: BTreeMap<String, BTreeMap<String, Vec<Option<f64>>>>,
    /// Statistic → the mean, over `split_half_reps` random splits of the real recordings into
    /// halves, of the 1-Wasserstein distance between the halves' values: what sampling alone
    /// gives between two sets of real recordings of half the size.
    #[serde(deserialize_with = "nan::map")]
    pub split_half: BTreeMap<String, f64>,
    /// Statistic → the split-half distance scaled to the comparison's sample sizes
    /// (× sqrt((1/n_real + 1/n_model) / (1/h1 + 1/h2)), W1 between samples of one
    /// distribution shrinking as the root of the sample size): the distance a model as varied
    /// as the real fish would show by chance.
    #[serde(deserialize_with = "nan::map")]
    pub floor: BTreeMap<String, f64>,
    /// Model → statistic → spread entry (`sim`: the model's recordings, in recording order;
    /// `ratio`: s.d. model / s.d. real).
    pub models: BTreeMap<String, BTreeMap<String, SpreadEntry>>,
    /// "real" or a model → the Spearman correlations between every two statistics across
    /// recordings.
    pub correlations: BTreeMap<String, Vec<Correlation>>,
}

/// Spearman's ρ between two statistics across recordings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Correlation {
    /// The first statistic.
    pub a: String,
    /// The second statistic.
    pub b: String,
    /// ρ (`scipy.stats.spearmanr`).
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub rho: f64,
    /// Its two-sided p-value.
    #[serde(default = "nan::nan", deserialize_with = "nan::f64")]
    pub p: f64,
    /// Recordings with both values.
    #[serde(default)]
    pub n: usize,
}

/// Every statistic's value for each recording (`None`: no value).
pub fn per_recording(values: &[RecordingValues]) -> Vec<Vec<Option<f64>>> {
    RECORDING_STATS
        .iter()
        .map(|s| {
            values
                .iter()
                .map(|v| (s.compute)(v).filter(|x| x.is_finite()))
                .collect()
        })
        .collect()
}

fn by_id(stats: &[Vec<Option<f64>>]) -> BTreeMap<String, Vec<Option<f64>>> {
    RECORDING_STATS
        .iter()
        .zip(stats)
        .map(|(s, v)| (s.id.to_string(), v.clone()))
        .collect()
}

fn present(v: &[Option<f64>]) -> Vec<f64> {
    v.iter().flatten().copied().collect()
}

/// The mean W1 between the two halves of `x` over `reps` random splits (NaN below 2 values).
pub fn split_half_w1(x: &[f64], reps: usize, rng: &mut SimRng) -> f64 {
    if x.len() < 2 {
        return f64::NAN;
    }
    let mut pool = x.to_vec();
    let h = pool.len() / 2;
    let mut total = 0.0;
    for _ in 0..reps {
        for i in 0..h {
            let j = rng.random_range(i..pool.len());
            pool.swap(i, j);
        }
        let (mut a, mut b) = (pool[..h].to_vec(), pool[h..].to_vec());
        a.sort_unstable_by(f64::total_cmp);
        b.sort_unstable_by(f64::total_cmp);
        total += st::wasserstein_sorted(&a, &b);
    }
    total / reps as f64
}

/// The split-half distance of `n` values scaled to a comparison of `n` against `m` values.
pub fn scaled_floor(split_half: f64, n: usize, m: usize) -> f64 {
    let h1 = (n / 2) as f64;
    let h2 = (n - n / 2) as f64;
    if h1 < 1.0 || m == 0 {
        return f64::NAN;
    }
    split_half * ((1.0 / n as f64 + 1.0 / m as f64) / (1.0 / h1 + 1.0 / h2)).sqrt()
}

/// Spearman correlations between every two statistics across recordings.
fn correlations(stats: &[Vec<Option<f64>>]) -> Vec<Correlation> {
    let mut out = Vec::new();
    for i in 0..stats.len() {
        for j in i + 1..stats.len() {
            let (x, y): (Vec<f64>, Vec<f64>) = stats[i]
                .iter()
                .zip(&stats[j])
                .filter_map(|(a, b)| Some(((*a)?, (*b)?)))
                .unzip();
            let r = st::spearman(&x, &y).ok();
            out.push(Correlation {
                a: RECORDING_STATS[i].id.into(),
                b: RECORDING_STATS[j].id.into(),
                rho: r.map_or(f64::NAN, |r| r.statistic),
                p: r.map_or(f64::NAN, |r| r.p),
                n: x.len(),
            });
        }
    }
    out
}

/// The spread section from the real recordings' values and each model's; `label` names the
/// comparison in the random streams ("offline" for pairs, "offline/open_loop").
pub fn offline_spread(
    real: &[RecordingValues],
    models: &[(String, Vec<RecordingValues>)],
    cfg: &OfflineConfig,
    seed: u64,
    label: &str,
) -> OfflineSpread {
    let real_stats = per_recording(real);
    let mut out = OfflineSpread {
        statistics: RECORDING_STATS.iter().map(|s| s.id.to_string()).collect(),
        ..OfflineSpread::default()
    };
    for (s, values) in RECORDING_STATS.iter().zip(&real_stats) {
        let x = present(values);
        let mut g = stream(seed, &format!("{label}/split_half/{}", s.id), 0);
        let half = split_half_w1(&x, cfg.split_half_reps, &mut g);
        out.split_half.insert(s.id.into(), half);
        let n_model = models
            .first()
            .map_or(x.len(), |(_, v)| x.len() * v.len() / real.len().max(1));
        out.floor
            .insert(s.id.into(), scaled_floor(half, x.len(), n_model));
    }
    out.values.insert("real".into(), by_id(&real_stats));
    out.correlations
        .insert("real".into(), correlations(&real_stats));
    for (name, values) in models {
        let stats = per_recording(values);
        let mut per = BTreeMap::new();
        for ((s, m), r) in RECORDING_STATS.iter().zip(&stats).zip(&real_stats) {
            let mut g = stream(seed, &format!("{label}/spread/{name}/{}", s.id), 0);
            if let Ok(e) = crate::spread::spread_entry(
                present(m),
                present(r),
                cfg.bootstrap_reps,
                cfg.ci_level,
                &mut g,
            ) {
                per.insert(s.id.to_string(), e);
            }
        }
        for e in per.values_mut() {
            // One model, one test per statistic: nothing to adjust across.
            e.bf_p_holm = e.bf_p;
        }
        out.models.insert(name.clone(), per);
        out.values.insert(name.clone(), by_id(&stats));
        out.correlations.insert(name.clone(), correlations(&stats));
    }
    out
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn split_half_of_two_values_is_their_distance_and_the_floor_scales_it() {
        let mut g = SimRng::seed_from_u64(1);
        assert_eq!(split_half_w1(&[1.0, 4.0], 10, &mut g), 3.0);
        assert!(split_half_w1(&[1.0], 10, &mut g).is_nan());
        // Halves of 26 and 27 against a comparison of 53 with 53.
        let f = scaled_floor(1.0, 53, 53);
        let want = ((2.0 / 53.0) / (1.0 / 26.0 + 1.0 / 27.0_f64)).sqrt();
        assert!((f - want).abs() < 1e-12 && f < 0.75, "{f}");
    }

    #[test]
    fn split_half_matches_the_expected_w1_of_two_samples_of_one_distribution() {
        // Uniform(0, 1): E[W1] between two samples of 50 is about 0.062 (numpy and scipy, 20,000
        // repetitions); the split-half of 100 values should be near it.
        let mut g = SimRng::seed_from_u64(3);
        let mut acc = 0.0;
        for _ in 0..40 {
            let x: Vec<f64> = (0..100).map(|_| g.random::<f64>()).collect();
            acc += split_half_w1(&x, 200, &mut g);
        }
        let mean = acc / 40.0;
        assert!((mean - 0.062).abs() < 0.01, "{mean}");
    }

    #[test]
    fn correlations_pair_every_two_statistics_over_shared_recordings() {
        let n = RECORDING_STATS.len();
        let mut stats = vec![vec![Some(1.0), Some(2.0), Some(3.0), None]; n];
        stats[1] = vec![Some(3.0), Some(2.0), Some(1.0), Some(9.0)];
        let c = correlations(&stats);
        assert_eq!(c.len(), n * (n - 1) / 2);
        assert_eq!(
            (c[0].a.as_str(), c[0].b.as_str()),
            ("mean_speed", "paused_fraction")
        );
        assert_eq!((c[0].rho, c[0].n), (-1.0, 3));
    }
}
