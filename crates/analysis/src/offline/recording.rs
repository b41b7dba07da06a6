//! A recording as the offline comparison sees it: the fish (a pair of live fish, or one fish
//! beside the robot) and, in a robot recording, the robot's path; and the same recording
//! simulated by a model: a model pair from the recording's first poses, or, open loop, a model
//! fish beside the robot's recorded path replayed as it was.

use super::OfflineConfig;
use crate::AnalysisError;
use fishprobe_io::{Entity, TrialFile};
use fishprobe_models::ModelSpec;
use fishprobe_sim::{AgentState, Sandbox, Tank, TankParams};

/// One agent's poses, frame by frame (NaN where untracked).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Track {
    /// Positions (cm).
    pub pos: Vec<[f32; 2]>,
    /// Headings (rad).
    pub heading: Vec<f32>,
}

impl Track {
    fn with_capacity(n: usize) -> Self {
        Self {
            pos: Vec::with_capacity(n),
            heading: Vec::with_capacity(n),
        }
    }

    /// The first frame with a position and a heading, as (x, y, heading).
    fn first_pose(&self) -> Option<[f32; 3]> {
        (0..self.pos.len().min(self.heading.len()))
            .find(|&t| {
                self.pos[t][0].is_finite()
                    && self.pos[t][1].is_finite()
                    && self.heading[t].is_finite()
            })
            .map(|t| [self.pos[t][0], self.pos[t][1], self.heading[t]])
    }
}

/// What a recording holds: two fish (a pair), or one fish and the robot.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// The fish (two in a pair recording, one in a robot recording).
    pub fish: Vec<Track>,
    /// The robot, in a robot recording.
    pub robot: Option<Track>,
    /// Frame rate (Hz).
    pub rate: f32,
}

impl Recording {
    /// Frames in which every agent has a slot (the shortest track).
    pub fn frames(&self) -> usize {
        self.fish
            .iter()
            .chain(&self.robot)
            .map(|t| t.pos.len().min(t.heading.len()))
            .min()
            .unwrap_or(0)
    }

    /// The agent each fish reacts to and is measured against: the robot in a robot
    /// recording, the other fish in a pair.
    pub fn other_of(&self, fish: usize) -> Option<&Track> {
        match &self.robot {
            Some(r) => Some(r),
            None => self.fish.get(1 - fish.min(1)),
        }
    }

    /// Whether it is a robot recording.
    pub fn has_robot(&self) -> bool {
        self.robot.is_some()
    }
}

/// A recording from a trial file: two fish without a robot (a pair), or one fish with the
/// robot; in the 100 x 100 cm tank. Fish headings are checked against motion as in the
/// ConvNet's dataset; the robot's come from its motion (`OfflineConfig::robot_heading`).
pub fn real_recording(t: &TrialFile, cfg: &OfflineConfig) -> Result<Recording, AnalysisError> {
    if (t.world_size_cm[0] - 100.0).abs() > 0.5 || (t.world_size_cm[1] - 100.0).abs() > 0.5 {
        return Err(format!(
            "world size {} x {} cm, not the 100 x 100 cm tank",
            t.world_size_cm[0], t.world_size_cm[1]
        )
        .into());
    }
    let fish: Vec<&Entity> = t.fish().collect();
    let robot = t.robot();
    match (fish.len(), robot) {
        (2, None) | (1, Some(_)) => {}
        (n, None) => return Err(format!("{n} fish and no robot, not a pair").into()),
        (n, Some(_)) => {
            return Err(format!("a robot and {n} fish, not one fish beside the robot").into())
        }
    }
    if fish.iter().chain(&robot).any(|f| f.nan_fraction() >= 1.0) {
        return Err("a track is all NaN".into());
    }
    let fish_track = |e: &Entity| Track {
        pos: e.positions.clone(),
        heading: e
            .headings_checked(cfg.motion_min_step_cm, cfg.heading_disagreement_rad)
            .0,
    };
    let robot = robot.map(|r| Track {
        pos: r.positions.clone(),
        heading: if cfg.robot_heading_from_motion {
            r.headings_from_motion(cfg.motion_min_step_cm)
        } else {
            r.headings()
        },
    });
    Ok(Recording {
        fish: fish.into_iter().map(fish_track).collect(),
        robot,
        rate: t.frame_rate_hz,
    })
}

/// The recording simulated by `model` at `OfflineConfig::model_rate_hz`, as long as the
/// recording: each fish starts from its live counterpart's first tracked pose (the tank's
/// centre facing +x if it has none); in a robot recording the robot's recorded path is
/// replayed as it was (open loop), resampled to the model's rate.
pub fn simulate(
    model: &ModelSpec,
    real: &Recording,
    cfg: &OfflineConfig,
    seed: u64,
) -> Result<Recording, AnalysisError> {
    let m = model.build().map_err(|e| e.to_string())?;
    simulate_model(&m, real, cfg, seed).map(|(r, _)| r)
}

/// [`simulate`] with a model already built, also giving the individual each simulated fish
/// was (neutral unless the model is a population).
pub fn simulate_model(
    m: &std::sync::Arc<dyn fishprobe_sim::FishModel>,
    real: &Recording,
    cfg: &OfflineConfig,
    seed: u64,
) -> Result<(Recording, Vec<fishprobe_sim::Individual>), AnalysisError> {
    let duration_s = real.frames() as f64 / f64::from(real.rate);
    let rate = cfg.model_rate_hz;
    let frames = (duration_s * f64::from(rate)).round() as usize;
    let starts: Vec<[f32; 3]> = real
        .fish
        .iter()
        .map(|f| f.first_pose().unwrap_or([0.0, 0.0, 0.0]))
        .collect();
    let tank = Tank::new(&TankParams::default());
    let mut sb = Sandbox::new(tank, rate, m.clone(), &starts, seed);
    let individuals = sb.minds().iter().map(|m| m.individual).collect();
    let robot = real
        .robot
        .as_ref()
        .map(|r| resample(r, real.rate, rate, frames));
    let mut fish: Vec<Track> = starts
        .iter()
        .map(|_| Track::with_capacity(frames))
        .collect();
    let mut scripted: Vec<AgentState> = Vec::with_capacity(1);
    for t in 0..frames {
        if t > 0 {
            // The fish moves from frame t - 1 to t seeing the robot where it was at t - 1.
            if let Some(r) = &robot {
                scripted.clear();
                scripted.extend(robot_state(r, t - 1, rate));
                sb.set_scripted(&scripted);
            }
            sb.step().map_err(|e| e.to_string())?;
        }
        for (track, s) in fish.iter_mut().zip(sb.fish()) {
            track.pos.push([s.x, s.y]);
            track.heading.push(s.heading);
        }
    }
    Ok((Recording { fish, robot, rate }, individuals))
}

/// The robot in frame `t` of a resampled track, with its velocity to the next frame; `None`
/// where it is untracked (the fish then sees no robot).
fn robot_state(r: &Track, t: usize, rate: f32) -> Option<AgentState> {
    let p = r.pos[t];
    let h = r.heading[t];
    if !(p[0].is_finite() && p[1].is_finite()) {
        return None;
    }
    let mut s = AgentState::at(p[0], p[1], if h.is_finite() { h } else { 0.0 });
    if let Some(q) = r
        .pos
        .get(t + 1)
        .filter(|q| q[0].is_finite() && q[1].is_finite())
    {
        s.vx = (q[0] - p[0]) * rate;
        s.vy = (q[1] - p[1]) * rate;
    }
    Some(s)
}

/// A track recorded at `from` Hz, at `to` Hz for `frames` frames: positions linearly
/// interpolated between the recorded frames around each time (NaN when either is untracked),
/// headings the earlier frame's.
pub fn resample(track: &Track, from: f32, to: f32, frames: usize) -> Track {
    let n = track.pos.len().min(track.heading.len());
    let mut out = Track::with_capacity(frames);
    for k in 0..frames {
        let x = k as f64 * f64::from(from) / f64::from(to);
        let i = (x.floor() as usize).min(n.saturating_sub(1));
        let j = (i + 1).min(n.saturating_sub(1));
        let w = (x - i as f64).clamp(0.0, 1.0) as f32;
        let (a, b) = (track.pos[i], track.pos[j]);
        out.pos
            .push([a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1])]);
        out.heading.push(track.heading[i]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resampling_interpolates_positions_and_holds_headings() {
        let t = Track {
            pos: vec![[0.0, 0.0], [4.0, 0.0], [8.0, f32::NAN]],
            heading: vec![0.0, 1.0, 2.0],
        };
        // 20 Hz to 25 Hz: times 0, 0.8, 1.6 recorded frames.
        let r = resample(&t, 20.0, 25.0, 3);
        assert_eq!(r.pos[0], [0.0, 0.0]);
        assert!((r.pos[1][0] - 3.2).abs() < 1e-5);
        assert!(r.pos[2][1].is_nan(), "next to an untracked frame");
        assert_eq!(r.heading, vec![0.0, 0.0, 1.0]);
    }

    #[test]
    fn the_other_agent_is_the_robot_or_the_other_fish() {
        let a = Track {
            pos: vec![[1.0, 0.0]],
            heading: vec![0.0],
        };
        let b = Track {
            pos: vec![[2.0, 0.0]],
            heading: vec![0.0],
        };
        let pair = Recording {
            fish: vec![a.clone(), b.clone()],
            robot: None,
            rate: 25.0,
        };
        assert_eq!(pair.other_of(0), Some(&b));
        assert_eq!(pair.other_of(1), Some(&a));
        let robot = Recording {
            fish: vec![a],
            robot: Some(b.clone()),
            rate: 20.0,
        };
        assert_eq!(robot.other_of(0), Some(&b));
    }
}
