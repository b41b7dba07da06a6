//! The offline comparison's measures, two tables: [`OFFLINE_METRICS`], the per-frame (or
//! per-fish) distributions pooled over recordings, each with the range its histograms span;
//! and [`RECORDING_STATS`], one value per recording, whose spread across recordings says how
//! much individuals differ. "The other agent" is the other fish in a pair recording and the
//! robot in a robot recording.

use super::recording::Recording;
use super::OfflineConfig;
use fishprobe_sim::{wrap_angle, Tank, TankParams};

/// One pooled measure.
#[derive(Debug, Clone, Copy)]
pub struct OfflineMetric {
    /// Its id in `offline.json` and the CSV.
    pub id: &'static str,
    /// Its unit.
    pub unit: &'static str,
    /// Its label in a pair recording.
    pub label: &'static str,
    /// Its label in a robot recording.
    pub label_robot: &'static str,
    /// The range of its histograms (values outside go to the edge bins).
    pub range: (f64, f64),
    /// What one value is.
    pub about: &'static str,
}

/// Index of each pooled measure in [`OFFLINE_METRICS`] and in [`RecordingValues::values`].
pub mod index {
    /// Speed.
    pub const SPEED: usize = 0;
    /// Absolute turn rate.
    pub const TURN: usize = 1;
    /// Distance to the nearest wall.
    pub const WALL: usize = 2;
    /// Distance to the other agent.
    pub const IID: usize = 3;
    /// Alignment with the other agent.
    pub const ALIGNMENT: usize = 4;
    /// The fish facing the other agent.
    pub const FACES: usize = 5;
    /// Paused fraction per fish.
    pub const PAUSED: usize = 6;
}

/// The pooled measures, in order.
pub const OFFLINE_METRICS: [OfflineMetric; 7] = [
    OfflineMetric {
        id: "speed",
        unit: "cm/s",
        label: "speed",
        label_robot: "fish speed",
        range: (0.0, 40.0),
        about: "per fish and frame, from consecutive positions",
    },
    OfflineMetric {
        id: "turn_rate",
        unit: "rad/s",
        label: "turn rate",
        label_robot: "fish turn rate",
        // |Δθ| at 25 Hz is at most π per frame: 78.5 rad/s.
        range: (0.0, 80.0),
        about: "absolute, per fish and frame",
    },
    OfflineMetric {
        id: "wall_distance",
        unit: "cm",
        label: "wall distance",
        label_robot: "fish wall distance",
        range: (0.0, 50.0),
        about: "to the nearest wall, per fish and frame",
    },
    OfflineMetric {
        id: "iid",
        unit: "cm",
        label: "inter-individual distance",
        label_robot: "robot-fish distance",
        range: (0.0, 142.0),
        about: "fish to the other agent, per frame",
    },
    OfflineMetric {
        id: "alignment",
        unit: "cos",
        label: "alignment",
        label_robot: "alignment with the robot",
        range: (-1.0, 1.0),
        about: "cos of the heading difference to the other agent, per frame",
    },
    OfflineMetric {
        id: "faces_other",
        unit: "cos",
        label: "fish faces the other",
        label_robot: "fish faces the robot",
        range: (-1.0, 1.0),
        about: "cos between the fish's heading and its line to the other agent, per fish and frame",
    },
    OfflineMetric {
        id: "paused",
        unit: "fraction",
        label: "paused",
        label_robot: "fish paused",
        range: (0.0, 1.0),
        about: "fraction of frames slower than `pause_cm_s`, per fish",
    },
];

impl OfflineMetric {
    /// Its label for a recording with or without a robot.
    pub fn label_for(&self, robot: bool) -> &'static str {
        if robot {
            self.label_robot
        } else {
            self.label
        }
    }
}

/// One recording's values of the pooled measures, and its pauses.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecordingValues {
    /// Per measure of [`OFFLINE_METRICS`], the values.
    pub values: Vec<Vec<f64>>,
    /// Speed values slower than `pause_cm_s` (over every fish).
    pub slow_frames: usize,
    /// Durations (s) of the pauses: runs of consecutive frames slower than `pause_cm_s`,
    /// over every fish.
    pub pauses_s: Vec<f64>,
}

fn finite2(q: [f32; 2]) -> bool {
    q[0].is_finite() && q[1].is_finite()
}

fn dist(a: [f32; 2], b: [f32; 2]) -> f64 {
    f64::from(((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt())
}

/// The pooled measures of a recording.
pub fn recording_values(r: &Recording, cfg: &OfflineConfig) -> RecordingValues {
    use index::*;
    let tank = Tank::new(&TankParams::default());
    let rate = f64::from(r.rate);
    let pause = f64::from(cfg.pause_cm_s);
    let frames = r.frames();
    let mut v = RecordingValues {
        values: vec![Vec::new(); OFFLINE_METRICS.len()],
        ..RecordingValues::default()
    };
    for (f, fish) in r.fish.iter().enumerate() {
        let other = r.other_of(f);
        let (mut slow, mut n, mut run) = (0usize, 0usize, 0usize);
        let end_run = |run: &mut usize, pauses: &mut Vec<f64>| {
            if *run > 0 {
                pauses.push(*run as f64 / rate);
                *run = 0;
            }
        };
        for t in 0..frames {
            let a = fish.pos[t];
            if !finite2(a) {
                end_run(&mut run, &mut v.pauses_s);
                continue;
            }
            v.values[WALL].push(f64::from(tank.wall_distance(a[0], a[1])));
            let h = fish.heading[t];
            if let Some(o) = other.filter(|o| finite2(o.pos[t]) && h.is_finite()) {
                let d = dist(a, o.pos[t]);
                if d > 1e-9 {
                    let (dx, dy) = (o.pos[t][0] - a[0], o.pos[t][1] - a[1]);
                    v.values[FACES].push((f64::from(h.cos() * dx + h.sin() * dy)) / d);
                }
            }
            if t + 1 < frames && finite2(fish.pos[t + 1]) {
                let s = dist(fish.pos[t + 1], a) * rate;
                v.values[SPEED].push(s);
                n += 1;
                if s < pause {
                    slow += 1;
                    run += 1;
                } else {
                    end_run(&mut run, &mut v.pauses_s);
                }
                let h1 = fish.heading[t + 1];
                if h.is_finite() && h1.is_finite() {
                    v.values[TURN].push(f64::from(wrap_angle(h1 - h).abs()) * rate);
                }
            } else {
                end_run(&mut run, &mut v.pauses_s);
            }
        }
        end_run(&mut run, &mut v.pauses_s);
        if n > 0 {
            v.values[PAUSED].push(slow as f64 / n as f64);
        }
        v.slow_frames += slow;
    }
    // Per frame, the first fish and its other agent.
    if let (Some(a), Some(b)) = (r.fish.first(), r.other_of(0)) {
        for t in 0..frames {
            if finite2(a.pos[t]) && finite2(b.pos[t]) {
                v.values[IID].push(dist(a.pos[t], b.pos[t]));
            }
            let (h0, h1) = (a.heading[t], b.heading[t]);
            if h0.is_finite() && h1.is_finite() {
                v.values[ALIGNMENT].push(f64::from((h0 - h1).cos()));
            }
        }
    }
    v
}

/// One value per recording.
#[derive(Debug, Clone, Copy)]
pub struct RecordingStat {
    /// Its id in `offline.json` and the CSV.
    pub id: &'static str,
    /// Its label with unit in a pair recording.
    pub label: &'static str,
    /// Its label with unit in a robot recording.
    pub label_robot: &'static str,
    /// How the recording's value is computed from its pooled values (`None`: no value).
    pub compute: fn(&RecordingValues) -> Option<f64>,
}

impl RecordingStat {
    /// Its label for a recording with or without a robot.
    pub fn label_for(&self, robot: bool) -> &'static str {
        if robot {
            self.label_robot
        } else {
            self.label
        }
    }
}

fn mean_of(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| fishprobe_stats::mean(v))
}

fn median_of(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| fishprobe_stats::median(v))
}

/// The per-recording statistics, in order: the issue of how much live fish differ is read
/// from their spread across recordings.
pub const RECORDING_STATS: [RecordingStat; 8] = [
    RecordingStat {
        id: "mean_speed",
        label: "mean speed (cm/s)",
        label_robot: "fish mean speed (cm/s)",
        compute: |v| mean_of(&v.values[index::SPEED]),
    },
    RecordingStat {
        id: "paused_fraction",
        label: "paused fraction",
        label_robot: "fish paused fraction",
        compute: |v| {
            let n = v.values[index::SPEED].len();
            (n > 0).then(|| v.slow_frames as f64 / n as f64)
        },
    },
    RecordingStat {
        id: "median_pause_s",
        label: "median pause (s)",
        label_robot: "fish median pause (s)",
        // A recording whose fish never pause has pauses of no length: 0, so that a model that
        // never pauses is compared, not left out.
        compute: |v| {
            (!v.values[index::SPEED].is_empty()).then(|| median_of(&v.pauses_s).unwrap_or(0.0))
        },
    },
    RecordingStat {
        id: "median_iid",
        label: "median IID (cm)",
        label_robot: "median robot-fish distance (cm)",
        compute: |v| median_of(&v.values[index::IID]),
    },
    RecordingStat {
        id: "median_wall_distance",
        label: "median wall distance (cm)",
        label_robot: "fish median wall distance (cm)",
        compute: |v| median_of(&v.values[index::WALL]),
    },
    RecordingStat {
        id: "mean_alignment",
        label: "mean alignment (cos)",
        label_robot: "mean alignment with the robot (cos)",
        compute: |v| mean_of(&v.values[index::ALIGNMENT]),
    },
    RecordingStat {
        id: "mean_turn_rate",
        label: "mean |turn rate| (rad/s)",
        label_robot: "fish mean |turn rate| (rad/s)",
        compute: |v| mean_of(&v.values[index::TURN]),
    },
    RecordingStat {
        id: "mean_faces_other",
        label: "fish faces the other (mean cos)",
        label_robot: "fish faces the robot (mean cos)",
        compute: |v| mean_of(&v.values[index::FACES]),
    },
];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::offline::recording::Track;

    fn pair() -> Recording {
        // Fish 0 moves 1 cm per frame along +x at 25 Hz, then stops for two frames; fish 1 sits
        // still facing +y, 10 cm above the origin.
        Recording {
            fish: vec![
                Track {
                    pos: vec![[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 0.0], [2.0, 0.0]],
                    heading: vec![0.0; 5],
                },
                Track {
                    pos: vec![[0.0, 10.0]; 5],
                    heading: vec![std::f32::consts::FRAC_PI_2; 5],
                },
            ],
            robot: None,
            rate: 25.0,
        }
    }

    #[test]
    fn pooled_values_by_hand() {
        let v = recording_values(&pair(), &OfflineConfig::default());
        use index::*;
        assert_eq!(v.values[SPEED][..4], [25.0, 25.0, 0.0, 0.0]);
        assert_eq!(v.values[SPEED][4..], [0.0; 4]);
        assert_eq!(v.values[PAUSED], vec![0.5, 1.0]);
        assert_eq!(v.slow_frames, 6);
        // Fish 0 pauses 2 frames (0.08 s); fish 1 the whole 4 frames (0.16 s).
        assert_eq!(v.pauses_s.len(), 2);
        assert!((v.pauses_s[0] - 0.08).abs() < 1e-12 && (v.pauses_s[1] - 0.16).abs() < 1e-12);
        assert!((v.values[IID][2] - (4.0f64 + 100.0).sqrt()).abs() < 1e-5);
        assert!(
            v.values[ALIGNMENT].iter().all(|c| c.abs() < 1e-6),
            "perpendicular"
        );
        assert_eq!(v.values[WALL][0], 50.0);
        // Fish 0 at the origin faces +x, the other straight above: cos 0. Fish 1 faces +y,
        // fish 0 below it: cos -1.
        assert!(v.values[FACES][0].abs() < 1e-6);
        assert!(
            (v.values[FACES][5] + 1.0).abs() < 1e-6,
            "{:?}",
            v.values[FACES]
        );
    }

    #[test]
    fn recording_statistics_by_hand() {
        let v = recording_values(&pair(), &OfflineConfig::default());
        let stat = |id: &str| {
            let s = RECORDING_STATS
                .iter()
                .find(|s| s.id == id)
                .expect("a statistic");
            (s.compute)(&v)
        };
        assert_eq!(stat("mean_speed"), Some(50.0 / 8.0));
        assert_eq!(stat("paused_fraction"), Some(0.75));
        assert!((stat("median_pause_s").unwrap_or(0.0) - 0.12).abs() < 1e-12);
        assert_eq!(stat("mean_alignment").map(|a| a.abs() < 1e-6), Some(true));
        let mut still = pair();
        still.fish[0] = still.fish[1].clone();
        still.fish[0].pos = vec![[5.0, 5.0]; 5];
        still.fish[1].pos[0] = [f32::NAN, 0.0];
        let v = recording_values(&still, &OfflineConfig::default());
        assert_eq!(
            (RECORDING_STATS[2].compute)(&v).map(|d| d > 0.0),
            Some(true)
        );
        let mut moving = pair();
        moving.fish[0].pos = (0..5).map(|t| [t as f32, 0.0]).collect();
        moving.fish[1].pos = (0..5).map(|t| [t as f32, 10.0]).collect();
        let v = recording_values(&moving, &OfflineConfig::default());
        assert_eq!((RECORDING_STATS[2].compute)(&v), Some(0.0), "no pause: 0 s");
    }
}
