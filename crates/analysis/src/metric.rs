//! The metrics, one table. Each entry of [`METRIC_TABLE`] is one metric: its id (the key in
//! `results.json` and the CSVs), its label with unit (figures and tables), whether it is of the
//! robot and a fish or of the group, what it means, and how one frame's value is computed. The
//! lists the analysis and the report use ([`METRICS`], [`GROUP_METRICS`], [`ALL_METRICS`],
//! [`METRIC_LABELS`]) and the counts their prose names ([`count_word`]) are derived from it,
//! so adding a metric is one entry here plus its computation.

use fishprobe_sim::wrap_angle;

/// One frame of a robot and one fish, for the pair metrics.
#[derive(Debug, Clone, Copy)]
pub struct PairFrame {
    /// Robot position (cm).
    pub robot: [f64; 2],
    /// Fish position (cm).
    pub fish: [f64; 2],
    /// Robot heading (rad).
    pub robot_heading: f64,
    /// Fish heading (rad, as stored).
    pub fish_heading: f32,
    /// The next frame's robot position, fish position and fish heading, when there is one.
    pub next: Option<([f64; 2], [f64; 2], f32)>,
    /// The active goal's centre (cm).
    pub goal: [f32; 2],
    /// Half the tank's width and height (cm).
    pub half: [f64; 2],
    /// Frames per second (differences are multiplied by it).
    pub rate: f64,
}

/// One frame of a group (two or more tracked fish), for the group metrics.
#[derive(Debug, Clone, Copy)]
pub struct GroupFrame {
    /// The group's order parameters.
    pub order: fishprobe_sim::GroupOrder,
    /// Robot-to-centroid distance (cm) and the fraction of the fish within reach of the robot,
    /// when the robot is tracked.
    pub robot: Option<(f32, f32)>,
}

/// How a metric's per-frame value is computed; `None`: no value in this frame.
#[derive(Debug, Clone, Copy)]
pub enum Compute {
    /// From the robot and one fish (a group's fish are pooled).
    Pair(fn(&PairFrame) -> Option<f64>),
    /// From the group as a whole (trials with two or more fish).
    Group(fn(&GroupFrame) -> Option<f64>),
}

/// One metric.
#[derive(Debug, Clone, Copy)]
pub struct Metric {
    /// Its id in `results.json` and the CSVs.
    pub id: &'static str,
    /// Its label with unit, in figures and tables.
    pub label: &'static str,
    /// What it measures.
    pub about: &'static str,
    /// How one frame's value is computed.
    pub compute: Compute,
    /// How a trial's frames become the one value of the trial in the between-trial spread
    /// (`spread`): the median for distances, which are skewed and have long tails when a fish
    /// wanders off; the mean of the absolute value for signed rates, whose mean is near zero
    /// in every trial (how fast, not which way); the mean otherwise.
    pub per_trial: PerTrial,
}

/// How a trial's per-frame values become one value of the trial.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PerTrial {
    /// The mean of the frames' values.
    Mean,
    /// The median of the frames' values.
    Median,
    /// The mean of the frames' absolute values.
    MeanAbsolute,
}

impl PerTrial {
    /// The trial's value from its frames' values, sorted ascending and finite (NaN without
    /// frames).
    pub fn of_sorted(self, sorted: &[f64]) -> f64 {
        if sorted.is_empty() {
            return f64::NAN;
        }
        let n = sorted.len() as f64;
        match self {
            Self::Mean => sorted.iter().sum::<f64>() / n,
            Self::MeanAbsolute => sorted.iter().map(|v| v.abs()).sum::<f64>() / n,
            Self::Median => fishprobe_stats::quantile_sorted(sorted, 0.5),
        }
    }

    /// In words, for tables and captions ("median", "mean", "mean |·|": of the absolute
    /// values).
    pub const fn word(self) -> &'static str {
        match self {
            Self::Mean => "mean",
            Self::Median => "median",
            Self::MeanAbsolute => "mean |·|",
        }
    }
}

impl Metric {
    /// Whether it is a group metric.
    pub const fn is_group(&self) -> bool {
        matches!(self.compute, Compute::Group(_))
    }
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

/// Every metric, pair metrics first (SPEC §8's nine), then the group metrics.
pub const METRIC_TABLE: [Metric; 15] = [
    Metric {
        id: "iid",
        label: "IID (cm)",
        about: "inter-individual distance, robot to fish",
        compute: Compute::Pair(|p| Some(dist(p.robot, p.fish))),
        per_trial: PerTrial::Median,
    },
    Metric {
        id: "iid_change",
        label: "IID change (cm/s)",
        about: "how fast the robot-fish distance changes",
        compute: Compute::Pair(|p| {
            p.next
                .map(|(r2, f2, _)| (dist(r2, f2) - dist(p.robot, p.fish)) * p.rate)
        }),
        per_trial: PerTrial::MeanAbsolute,
    },
    Metric {
        id: "alignment",
        label: "alignment (cos)",
        about: "cosine of the angle between robot and fish headings",
        compute: Compute::Pair(|p| Some((p.robot_heading - f64::from(p.fish_heading)).cos())),
        per_trial: PerTrial::Mean,
    },
    Metric {
        id: "fish_speed",
        label: "fish speed (cm/s)",
        about: "the fish's speed",
        compute: Compute::Pair(|p| p.next.map(|(_, f2, _)| dist(f2, p.fish) * p.rate)),
        per_trial: PerTrial::Mean,
    },
    Metric {
        id: "fish_turn",
        label: "fish turn (rad/s)",
        about: "the fish's turn rate",
        compute: Compute::Pair(|p| {
            p.next
                .map(|(_, _, h2)| f64::from(wrap_angle(h2 - p.fish_heading)) * p.rate)
        }),
        per_trial: PerTrial::MeanAbsolute,
    },
    Metric {
        id: "fish_goal_distance",
        label: "fish-goal dist. (cm)",
        about: "distance of the fish to the active goal's centre",
        compute: Compute::Pair(|p| {
            Some(
                ((p.fish[0] - f64::from(p.goal[0])).powi(2)
                    + (p.fish[1] - f64::from(p.goal[1])).powi(2))
                .sqrt(),
            )
        }),
        per_trial: PerTrial::Median,
    },
    Metric {
        id: "fish_faces_robot",
        label: "fish faces robot (cos)",
        about: "cosine of the angle between the fish's heading and its line to the robot",
        compute: Compute::Pair(|p| {
            let iid = dist(p.robot, p.fish);
            let th = f64::from(p.fish_heading);
            (iid > 1e-9).then(|| {
                (th.cos() * (p.robot[0] - p.fish[0]) + th.sin() * (p.robot[1] - p.fish[1])) / iid
            })
        }),
        per_trial: PerTrial::Mean,
    },
    Metric {
        id: "wall_distance",
        label: "wall distance (cm)",
        about: "the fish's distance to the nearest wall",
        compute: Compute::Pair(|p| {
            let (dx, dy) = (p.half[0] - p.fish[0].abs(), p.half[1] - p.fish[1].abs());
            Some(dx.min(dy))
        }),
        per_trial: PerTrial::Median,
    },
    Metric {
        id: "wall_alignment",
        label: "wall alignment (|cos|)",
        about: "|cos| between the fish's heading and the nearest wall",
        compute: Compute::Pair(|p| {
            let (dx, dy) = (p.half[0] - p.fish[0].abs(), p.half[1] - p.fish[1].abs());
            let th = f64::from(p.fish_heading);
            // |ê_f · t|: along a left/right wall t = (0, 1), along a top/bottom wall t = (1, 0).
            Some(if dx <= dy {
                th.sin().abs()
            } else {
                th.cos().abs()
            })
        }),
        per_trial: PerTrial::Mean,
    },
    Metric {
        id: "polarisation",
        label: "polarisation",
        about: "|mean heading| of the fish",
        compute: Compute::Group(|g| Some(f64::from(g.order.polarisation))),
        per_trial: PerTrial::Mean,
    },
    Metric {
        id: "milling",
        label: "milling",
        about: "Couzin's group angular momentum",
        compute: Compute::Group(|g| Some(f64::from(g.order.milling))),
        per_trial: PerTrial::Mean,
    },
    Metric {
        id: "mean_nnd",
        label: "mean NND (cm)",
        about: "mean nearest-neighbour distance",
        compute: Compute::Group(|g| Some(f64::from(g.order.mean_nnd_cm))),
        per_trial: PerTrial::Median,
    },
    Metric {
        id: "group_spread",
        label: "group spread (cm)",
        about: "mean distance of the fish from their centroid",
        compute: Compute::Group(|g| Some(f64::from(g.order.spread_cm))),
        per_trial: PerTrial::Median,
    },
    Metric {
        id: "robot_centroid_distance",
        label: "robot-centroid dist. (cm)",
        about: "distance of the robot to the fish's centroid",
        compute: Compute::Group(|g| g.robot.map(|(d, _)| f64::from(d))),
        per_trial: PerTrial::Median,
    },
    Metric {
        id: "fish_near_robot",
        label: "fish near robot (frac.)",
        about: "fraction of the fish within `robot_reach_cm` of the robot",
        compute: Compute::Group(|g| g.robot.map(|(_, near)| f64::from(near))),
        per_trial: PerTrial::Mean,
    },
];

const fn count_pair() -> usize {
    let mut n = 0;
    let mut i = 0;
    while i < METRIC_TABLE.len() {
        if !METRIC_TABLE[i].is_group() {
            n += 1;
        }
        i += 1;
    }
    n
}

/// How many pair metrics there are.
pub const PAIR_METRIC_COUNT: usize = count_pair();

/// The ids of the table's metrics whose kind is `group` (in table order), as an array.
const fn ids<const N: usize>(group: bool) -> [&'static str; N] {
    let mut out = [""; N];
    let (mut i, mut k) = (0, 0);
    while i < METRIC_TABLE.len() {
        if METRIC_TABLE[i].is_group() == group {
            out[k] = METRIC_TABLE[i].id;
            k += 1;
        }
        i += 1;
    }
    out
}

const fn check_pairs_first() -> bool {
    let mut i = PAIR_METRIC_COUNT;
    while i < METRIC_TABLE.len() {
        if !METRIC_TABLE[i].is_group() {
            return false;
        }
        i += 1;
    }
    true
}

// Index `m` of a trial's metrics is `ALL_METRICS[m]`: the pair metrics first.
const _: () = assert!(
    check_pairs_first(),
    "pair metrics come first in METRIC_TABLE"
);

/// The index of the metric `id` in a trial's metrics ([`METRIC_TABLE`]'s order). Used in a
/// constant (as [`IID`]), an id no metric has is a compile-time error: there is no fallback.
pub const fn metric_index(id: &str) -> usize {
    let want = id.as_bytes();
    let mut i = 0;
    while i < METRIC_TABLE.len() {
        let have = METRIC_TABLE[i].id.as_bytes();
        if have.len() == want.len() {
            let mut j = 0;
            while j < have.len() && have[j] == want[j] {
                j += 1;
            }
            if j == have.len() {
                return i;
            }
        }
        i += 1;
    }
    panic!("no metric has this id")
}

/// The inter-individual distance's index in a trial's metrics (the report's IID figure).
pub const IID: usize = metric_index("iid");

/// The pair metrics' ids, in the order of a trial's metrics.
pub const METRICS: [&str; PAIR_METRIC_COUNT] = ids(false);

/// The group metrics' ids (trials with two or more fish), following the pair metrics.
pub const GROUP_METRICS: [&str; METRIC_TABLE.len() - PAIR_METRIC_COUNT] = ids(true);

const fn all<const N: usize>(label: bool) -> [&'static str; N] {
    let mut out = [""; N];
    let mut i = 0;
    while i < N {
        out[i] = if label {
            METRIC_TABLE[i].label
        } else {
            METRIC_TABLE[i].id
        };
        i += 1;
    }
    out
}

/// Every metric's id, pair metrics first: index `m` of a trial's metrics is `ALL_METRICS[m]`.
pub const ALL_METRICS: [&str; METRIC_TABLE.len()] = all(false);

/// Every metric's label with unit, in [`ALL_METRICS`] order.
pub const METRIC_LABELS: [&str; METRIC_TABLE.len()] = all(true);

/// A count as prose says it ("nine", "six"); digits from thirteen on.
pub fn count_word(n: usize) -> String {
    const WORDS: [&str; 13] = [
        "no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten",
        "eleven", "twelve",
    ];
    WORDS
        .get(n)
        .map_or_else(|| n.to_string(), |w| (*w).to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_are_found_by_id() {
        assert_eq!(METRIC_TABLE[IID].id, "iid");
        for (i, m) in METRIC_TABLE.iter().enumerate() {
            assert_eq!(metric_index(m.id), i);
        }
        assert!(std::panic::catch_unwind(|| metric_index("no-such-metric")).is_err());
    }

    #[test]
    fn the_lists_are_the_tables_and_ids_are_unique() {
        assert_eq!(METRICS.len() + GROUP_METRICS.len(), ALL_METRICS.len());
        assert_eq!(&ALL_METRICS[..METRICS.len()], &METRICS[..]);
        assert_eq!(&ALL_METRICS[METRICS.len()..], &GROUP_METRICS[..]);
        let mut ids = ALL_METRICS.to_vec();
        ids.sort_unstable();
        ids.dedup();
        assert_eq!(ids.len(), ALL_METRICS.len(), "a metric id is used twice");
        assert!(METRIC_LABELS.iter().all(|l| !l.is_empty()));
        assert!(ALL_METRICS.iter().all(|l| !l.is_empty()));
        assert_eq!(count_word(9), "nine");
        assert_eq!(count_word(6), "six");
        assert_eq!(count_word(16), "16");
    }
}
