//! An OOD score from the model's own uncertainty: the disagreement of an ensemble
//! of M_ConvNet fits.
//!
//! The support score ([`crate::support`]) measures how *rare* a view was in the training
//! recordings. A rare view need not be one the model gets wrong: the in-silico loop
//! (docs/validation.md, "Probes that seek what the data lacks") found the
//! OOD robot's rare situations to be ones the fish answers simply. An ensemble of networks
//! fitted on the same data from different initialisations and shuffles agrees where the data
//! pins the answer down and disagrees where each network had to extrapolate (deep ensembles,
//! Lakshminarayanan et al. 2017). Its disagreement on a view is the **mutual information**
//! between the prediction and the member (Houlsby et al. 2011, "BALD"):
//!
//! `I(view) = H(mean_k p_k) − mean_k H(p_k)`, in nats,
//!
//! with `p_k` member k's distribution over the (v, ω) grid. It is 0 when every member predicts
//! the same distribution, however broad, so a fish that is merely unpredictable (a broad but
//! agreed answer) does not count, only a fish the data did not teach the model. Calibrated as
//! the support score is: 0 at the training views' median, 1 at their 95th percentile.
//!
//! `fishprobe fit-convnet --members K` fits the K − 1 further members beside the weights
//! (`WEIGHTS.member-2.safetensors`, ...) and writes `WEIGHTS.disagreement.json`: the members'
//! file names and SHA-256s, the weights' SHA-256 and the calibration. The OOD task uses it with
//! `[env.task] ood_score = "disagreement"`.

use crate::convnet::{encode_view, encode_views, ConvNet, ConvNetArch, ConvNetWorkspace};
use crate::support::{calibrated, draw, quantile, SupportError};
use fishprobe_nn::PackedMlp;
use fishprobe_sim::{AgentState, FishView, InputSupport, SimRng, Tank};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Format name written into disagreement files.
const FORMAT: &str = "fishprobe-disagreement";
/// Format version.
const VERSION: u32 = 1;
/// Largest disagreement file read (it holds names and numbers only).
pub const MAX_FILE_BYTES: u64 = 1 << 20;
/// Most members of an ensemble (the model's own weights included): the score costs one
/// network evaluation per member.
pub const MAX_MEMBERS: usize = 16;

/// The disagreement file of a weights file: `WEIGHTS.disagreement.json` beside it.
pub fn file_beside(weights: &Path) -> PathBuf {
    let mut s = weights.as_os_str().to_owned();
    s.push(".disagreement.json");
    PathBuf::from(s)
}

/// The file of further member `i` (2, 3, ...) of the ensemble of `weights`:
/// `WEIGHTS.member-I.safetensors` beside it.
pub fn member_beside(weights: &Path, i: usize) -> PathBuf {
    let mut s = weights.as_os_str().to_owned();
    s.push(format!(".member-{i}.safetensors"));
    PathBuf::from(s)
}

/// A further member as the file names it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MemberRef {
    /// File name, in the directory of the disagreement file (no directories).
    pub file: String,
    /// Its SHA-256.
    pub sha256: String,
}

/// What a disagreement file holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DisagreementFile {
    /// Always "fishprobe-disagreement".
    pub format: String,
    /// Format version (1).
    pub version: u32,
    /// The model the ensemble belongs to (its weights file).
    pub model: String,
    /// SHA-256 of the model's weights: the ensemble's first member.
    pub model_sha256: String,
    /// The further members.
    pub members: Vec<MemberRef>,
    /// Median of the raw disagreement (nats) over the calibration views.
    pub raw_median: f32,
    /// Its 95th percentile.
    pub raw_p95: f32,
    /// Training views it was calibrated on.
    pub calibration_views: usize,
    /// Free notes: the command, the training files.
    #[serde(default)]
    pub provenance: serde_json::Value,
}

impl DisagreementFile {
    /// The file of an ensemble not yet calibrated ([`Disagreement::fit`] calibrates it).
    pub fn new(
        model: String,
        model_sha256: String,
        members: Vec<MemberRef>,
        provenance: serde_json::Value,
    ) -> Self {
        Self {
            format: FORMAT.into(),
            version: VERSION,
            model,
            model_sha256,
            members,
            raw_median: 0.0,
            raw_p95: 1.0,
            calibration_views: 0,
            provenance,
        }
    }
}

/// Buffers of one concurrent score (sized by the largest batch seen; no allocation after).
#[derive(Debug, Default)]
struct Scratch {
    /// Encoded views (`batch x view_len`).
    x: Vec<f32>,
    ws: ConvNetWorkspace,
    /// One member's distributions (`batch x cells`).
    p: Vec<f32>,
    /// The members' mean distributions (`batch x cells`).
    mean: Vec<f32>,
    /// The members' mean entropy, per view.
    mean_h: Vec<f32>,
    /// Raw disagreements, per view.
    raw: Vec<f32>,
}

/// The ensemble and its calibration: an [`InputSupport`].
#[derive(Debug)]
pub struct Disagreement {
    /// What the file says.
    pub file: DisagreementFile,
    /// The model's own network first, then the further members.
    nets: Vec<ConvNet>,
    /// Their dense layers packed for inference (as the ConvNet fish's): a view's score is the
    /// same bits in any batch, and no weight is repacked per call.
    dense: Vec<PackedMlp>,
    scratch: Vec<Mutex<Scratch>>,
}

/// Entropy (nats) of a distribution.
fn entropy(p: &[f32]) -> f32 {
    -p.iter()
        .filter(|&&q| q > 0.0)
        .map(|&q| q * q.ln())
        .sum::<f32>()
}

/// Entropy (nats) of `p`, the softmax of the logits `z`, with one logarithm instead of one
/// per cell: `-ln p_i = lse - z_i` with `lse = z_j - ln p_j` at the most likely cell `j`.
fn softmax_entropy(z: &[f32], p: &[f32]) -> f32 {
    let mut j = 0;
    for (i, &q) in p.iter().enumerate() {
        if q > p[j] {
            j = i;
        }
    }
    let lse = z[j] - p[j].ln();
    let (mut mass, mut dot) = (0.0f32, 0.0f32);
    for (&q, &zi) in p.iter().zip(z) {
        mass += q;
        dot += q * zi;
    }
    (lse * mass - dot).max(0.0)
}

impl Disagreement {
    /// The ensemble of `nets` (the model's own first; at least 2, all of one shape),
    /// calibrated on up to `calibration_views` of the training views `views` (`n x view_len`)
    /// drawn with `rng`. `file` supplies the names; its calibration is overwritten.
    pub fn fit(
        nets: Vec<ConvNet>,
        mut file: DisagreementFile,
        views: &[f32],
        calibration_views: usize,
        rng: &mut SimRng,
    ) -> Result<Self, SupportError> {
        let len = nets.first().map_or(1, |n| n.arch.view_len());
        let n = views.len() / len;
        let k = calibration_views.min(n);
        if k < 20 {
            return Err(SupportError::TooFewViews { got: n, need: 20 });
        }
        file.raw_median = 0.0;
        file.raw_p95 = 1.0;
        file.calibration_views = k;
        let mut d = Self::new(nets, file).map_err(|what| SupportError::Invalid {
            path: "(new ensemble)".into(),
            what,
        })?;
        let mut raw: Vec<f32> = draw(n, k, rng)
            .iter()
            .map(|&i| d.raw_view(&views[i * len..(i + 1) * len]))
            .collect();
        let (median, p95) = (quantile(&mut raw, 0.5), quantile(&mut raw, 0.95));
        d.file.raw_median = median;
        // Degenerate (members that agree everywhere on this data): any spread above counts.
        d.file.raw_p95 = if p95 > median { p95 } else { median + 1e-6 };
        Ok(d)
    }

    /// Checks the networks against the file and builds the scratch buffers.
    fn new(nets: Vec<ConvNet>, file: DisagreementFile) -> Result<Self, String> {
        if !(2..=MAX_MEMBERS).contains(&nets.len()) || nets.len() != file.members.len() + 1 {
            return Err(format!(
                "{} networks for {} further members: an ensemble has 2 to {MAX_MEMBERS}",
                nets.len(),
                file.members.len()
            ));
        }
        if nets.iter().any(|n| n.arch != nets[0].arch) {
            return Err("members of different shapes".into());
        }
        let dense = nets.iter().map(|n| PackedMlp::new(&n.mlp)).collect();
        let scratch = crate::convnet::slots(Scratch::default);
        Ok(Self {
            file,
            nets,
            dense,
            scratch,
        })
    }

    /// Members, the model's own network included.
    pub fn members(&self) -> usize {
        self.nets.len()
    }

    /// The raw disagreement (mutual information, nats) of a view (`3 x bins`).
    pub fn raw_view(&self, view: &[f32]) -> f32 {
        let mut guard = crate::convnet::free_slot(&self.scratch);
        let s = &mut *guard;
        s.x.clear();
        s.x.extend_from_slice(view);
        self.raw_batch(1, s);
        s.raw[0]
    }

    /// The raw disagreements of the `batch` views in `s.x`, into `s.raw`. The members run
    /// one at a time over the whole batch, so each member's weights are read once per batch.
    fn raw_batch(&self, batch: usize, s: &mut Scratch) {
        let cells = self.nets[0].arch.cells();
        s.p.resize(batch * cells, 0.0);
        s.mean.resize(batch * cells, 0.0);
        s.mean.fill(0.0);
        s.mean_h.resize(batch, 0.0);
        s.mean_h.fill(0.0);
        s.raw.resize(batch, 0.0);
        let w = 1.0 / self.nets.len() as f32;
        for (net, dense) in self.nets.iter().zip(&self.dense) {
            net.features(&s.x, batch, &mut s.ws);
            // A network with an individual's latent sees the population's centre here.
            let logits = if net.arch.latent_dim > 0 {
                net.join_latent(None, batch, &mut s.ws);
                dense.forward(&s.ws.mlp_in, batch, &mut s.ws.mlp)
            } else {
                dense.forward(&s.ws.conv_out, batch, &mut s.ws.mlp)
            };
            fishprobe_nn::dist::softmax_rows(logits, &mut s.p, cells);
            for (((z, p), m), h) in logits
                .chunks_exact(cells)
                .zip(s.p.chunks_exact(cells))
                .zip(s.mean.chunks_exact_mut(cells))
                .zip(&mut s.mean_h)
            {
                *h += w * softmax_entropy(z, p);
                for (m, &q) in m.iter_mut().zip(p) {
                    *m += w * q;
                }
            }
        }
        for ((r, m), &h) in s
            .raw
            .iter_mut()
            .zip(s.mean.chunks_exact(cells))
            .zip(&s.mean_h)
        {
            // Rounding can leave a hair below 0 where the members agree.
            *r = (entropy(m) - h).max(0.0);
        }
    }

    /// The calibrated score of a raw disagreement: 0 at the calibration views' median, 1 at
    /// their 95th percentile, never negative; a non-finite value counts as far outside.
    pub fn calibrate(&self, raw: f32) -> f32 {
        calibrated(raw, self.file.raw_median, self.file.raw_p95)
    }

    /// The view layout of the members.
    pub fn arch(&self) -> &ConvNetArch {
        &self.nets[0].arch
    }

    /// The score of the view of fish `me` among `others` in `tank`. Allocates nothing once
    /// the scratch buffers are sized.
    pub fn score_agents(&self, tank: &Tank, me: &AgentState, others: &[AgentState]) -> f32 {
        let mut guard = crate::convnet::free_slot(&self.scratch);
        let s = &mut *guard;
        let arch = &self.nets[0].arch;
        s.x.resize(arch.view_len(), 0.0);
        encode_view(arch, tank, me, others, &mut s.x);
        self.raw_batch(1, s);
        self.calibrate(s.raw[0])
    }

    /// The score of a view (`3 x bins`).
    pub fn score_view(&self, view: &[f32]) -> f32 {
        self.calibrate(self.raw_view(view))
    }

    /// Writes the disagreement file (atomically) to `path`; the members' files are the
    /// caller's (they are named relative to `path`'s directory).
    pub fn save(&self, path: &Path) -> Result<(), SupportError> {
        let err = |e: String| SupportError::Write {
            path: path.to_path_buf(),
            what: e,
        };
        let text = serde_json::to_string_pretty(&self.file).map_err(|e| err(e.to_string()))?;
        let tmp = path.with_extension("json.tmp");
        std::fs::write(&tmp, text).map_err(|e| err(e.to_string()))?;
        std::fs::rename(&tmp, path).map_err(|e| err(e.to_string()))
    }

    /// Reads the disagreement file of `weights` (named `model` in messages) and its members,
    /// and checks them: format, size, that it belongs to these weights (`weights_sha256`) and
    /// that each member is the file it was fitted as (by SHA-256).
    pub fn load(weights: &Path, model: &str, weights_sha256: &str) -> Result<Self, SupportError> {
        let path = file_beside(weights);
        let invalid = |what: String| SupportError::Invalid {
            path: path.display().to_string(),
            what,
        };
        let text = crate::support::read_file_beside(
            &path,
            (
                MAX_FILE_BYTES,
                "fishprobe_models::disagreement::MAX_FILE_BYTES",
            ),
            || SupportError::MissingEnsemble {
                model: model.into(),
                path: path.clone(),
            },
        )?;
        let file: DisagreementFile = serde_json::from_str(&text)
            .map_err(|e| invalid(format!("not a fishprobe disagreement file: {e}")))?;
        if file.format != FORMAT || file.version != VERSION {
            return Err(invalid(format!(
                "format {} version {}, not {FORMAT} version {VERSION}",
                file.format, file.version
            )));
        }
        if file.model_sha256 != weights_sha256 {
            return Err(invalid(format!(
                "fitted for the weights with SHA-256 {}, not for {model} (SHA-256 \
                 {weights_sha256}): refit with `fishprobe fit-convnet --members K`",
                file.model_sha256
            )));
        }
        let ok = file.raw_median.is_finite()
            && file.raw_p95.is_finite()
            && file.raw_p95 > file.raw_median;
        if !ok {
            return Err(invalid("non-finite or degenerate calibration".into()));
        }
        if !(1..MAX_MEMBERS).contains(&file.members.len()) {
            return Err(invalid(format!(
                "{} further members: an ensemble has 2 to {MAX_MEMBERS} in all",
                file.members.len()
            )));
        }
        let dir = path.parent().unwrap_or(Path::new("."));
        let mut nets = vec![ConvNet::load(weights).map_err(|e| invalid(e.to_string()))?];
        for m in &file.members {
            // A bare file name: the file cannot point outside its directory.
            if Path::new(&m.file).file_name().and_then(|n| n.to_str()) != Some(m.file.as_str()) {
                return Err(invalid(format!(
                    "member `{}` is not a file name in the file's directory",
                    m.file
                )));
            }
            let p = dir.join(&m.file);
            let sha = crate::weights_sha256(&p)
                .map_err(|e| invalid(format!("member {}: {e}", p.display())))?;
            if sha != m.sha256 {
                return Err(invalid(format!(
                    "member {} has SHA-256 {sha}, not the {} it was fitted as: refit with \
                     `fishprobe fit-convnet --members K`",
                    p.display(),
                    m.sha256
                )));
            }
            nets.push(ConvNet::load(&p).map_err(|e| invalid(e.to_string()))?);
        }
        Self::new(nets, file).map_err(invalid)
    }
}

impl InputSupport for Disagreement {
    fn score(&self, view: &FishView) -> f32 {
        self.score_agents(&view.tank, &view.me, view.others())
    }

    /// All `views` through each member at once: the score of a view is the same bits as
    /// alone, at a fraction of the cost per view (docs/validation.md, "Probes that seek what the data lacks").
    fn score_batch(&self, views: &[FishView], out: &mut [f32]) {
        let mut guard = crate::convnet::free_slot(&self.scratch);
        let s = &mut *guard;
        let arch = &self.nets[0].arch;
        s.x.resize(views.len() * arch.view_len(), 0.0);
        encode_views(arch, views, &mut s.x);
        self.raw_batch(views.len(), s);
        for (o, &r) in out.iter_mut().zip(&s.raw) {
            *o = self.calibrate(r);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fishprobe_sim::stream;
    use rand::RngExt;

    fn file(members: usize) -> DisagreementFile {
        let refs = (0..members)
            .map(|i| MemberRef {
                file: format!("m{i}"),
                sha256: String::new(),
            })
            .collect();
        DisagreementFile::new("test".into(), String::new(), refs, serde_json::Value::Null)
    }

    #[test]
    fn mutual_information_by_hand() {
        // Two members over two cells with logits (0, ln 3) and (ln 3, 0): p = (1/4, 3/4) and
        // (3/4, 1/4). Their mean is (1/2, 1/2): I = ln 2 − H(1/4, 3/4)
        //   = 0.693147 − 0.562335 = 0.130812 nats.
        let arch = ConvNetArch {
            v_bins: 1,
            w_bins: 2,
            ..ConvNetArch::default()
        };
        let mut rng = stream(1, "t", 0);
        let mut a = ConvNet::new(arch.clone(), &mut rng);
        // Zero weights, biases as the logits: every view gets the same distribution.
        let set = |net: &mut ConvNet, l: [f32; 2]| {
            let p = net.mlp.params_mut();
            p.fill(0.0);
            // The output layer's bias is the last of the parameters.
            let n = p.len();
            p[n - 2..].copy_from_slice(&l);
        };
        let mut b = a.clone();
        set(&mut a, [0.0, 3f32.ln()]);
        set(&mut b, [3f32.ln(), 0.0]);
        let d = Disagreement::new(vec![a.clone(), b], file(1)).unwrap();
        let view = vec![0.0; arch.view_len()];
        assert!((d.raw_view(&view) - 0.130_812).abs() < 1e-5);
        // Members that agree, however broad their answer, do not disagree.
        let same = Disagreement::new(vec![a.clone(), a], file(1)).unwrap();
        assert!(same.raw_view(&view).abs() < 1e-6);
    }

    #[test]
    fn a_views_score_is_the_same_in_any_batch_and_the_one_logarithm_entropy_is_the_entropy() {
        let mut rng = stream(3, "t", 0);
        let arch = ConvNetArch::default();
        let nets: Vec<ConvNet> = (0..3)
            .map(|_| ConvNet::new(arch.clone(), &mut rng))
            .collect();
        let mut f = file(2);
        f.raw_p95 = 0.01;
        let d = Disagreement::new(nets, f).unwrap();
        let tank = Tank::default();
        let views: Vec<FishView> = (0..40)
            .map(|_| {
                let mut agent = || AgentState {
                    x: rng.random_range(-45.0..45.0),
                    y: rng.random_range(-45.0..45.0),
                    heading: rng.random_range(-3.1..3.1),
                    ..AgentState::default()
                };
                let (me, robot) = (agent(), agent());
                FishView::build(0, &[me], &[robot], tank, 0.04, 0.0)
            })
            .collect();
        let mut batch = vec![0.0; views.len()];
        d.score_batch(&views, &mut batch);
        let exact = fishprobe_nn::gemm::avx2_fma_supported();
        for (v, &b) in views.iter().zip(&batch) {
            let alone = d.score(v);
            assert!(alone.is_finite() && alone >= 0.0);
            if exact {
                assert_eq!(
                    alone.to_bits(),
                    b.to_bits(),
                    "{alone} alone, {b} in a batch"
                );
            } else {
                assert!((alone - b).abs() <= 1e-5 * alone.max(1.0), "{alone} vs {b}");
            }
        }
        assert!(
            batch.iter().any(|&b| b > 0.0),
            "random members must disagree somewhere"
        );
        // The entropy from the logits with one logarithm agrees with -sum p ln p.
        let z: Vec<f32> = (0..1025).map(|_| rng.random_range(-6.0..6.0)).collect();
        let mut p = vec![0.0; z.len()];
        fishprobe_nn::dist::softmax_rows(&z, &mut p, z.len());
        let (fast, slow) = (softmax_entropy(&z, &p), entropy(&p));
        assert!((fast - slow).abs() < 1e-4 * slow, "{fast} vs {slow}");
    }

    #[test]
    fn a_saved_ensemble_loads_and_a_foreign_or_hostile_file_is_refused_by_name() {
        let dir =
            std::env::temp_dir().join(format!("fishprobe-disagreement-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let arch = ConvNetArch::default();
        let mut rng = stream(4, "t", 0);
        let weights = dir.join("w.safetensors");
        let member = member_beside(&weights, 2);
        let nets: Vec<ConvNet> = (0..2)
            .map(|_| ConvNet::new(arch.clone(), &mut rng))
            .collect();
        let meta = serde_json::json!({ "arch": arch });
        fishprobe_nn::store::save(&weights, &nets[0].to_tensors(), &meta).unwrap();
        fishprobe_nn::store::save(&member, &nets[1].to_tensors(), &meta).unwrap();
        let sha = |p: &Path| crate::sha256_hex(&std::fs::read(p).unwrap());
        let refs = vec![MemberRef {
            file: member.file_name().unwrap().to_string_lossy().into_owned(),
            sha256: sha(&member),
        }];
        let f = DisagreementFile::new("w".into(), sha(&weights), refs, Default::default());
        let views: Vec<f32> = (0..100 * arch.view_len())
            .map(|_| rng.random_range(0.0..1.0))
            .collect();
        let d = Disagreement::fit(nets, f, &views, 50, &mut rng).unwrap();
        let path = file_beside(&weights);
        d.save(&path).unwrap();
        let back = Disagreement::load(&weights, "w", &sha(&weights)).unwrap();
        assert_eq!(back.file, d.file);
        assert_eq!(
            back.score_view(&views[..arch.view_len()]),
            d.score_view(&views[..arch.view_len()])
        );
        let refused = |text: String, says: &str| {
            std::fs::write(&path, text).unwrap();
            let e = Disagreement::load(&weights, "w", &sha(&weights))
                .unwrap_err()
                .to_string();
            assert!(e.contains(says), "{says}: {e}");
        };
        let good = serde_json::to_value(&d.file).unwrap();
        // Another model's ensemble.
        let mut other = good.clone();
        other["model_sha256"] = "00".into();
        refused(other.to_string(), "refit with");
        // A member named outside the file's directory.
        let mut outside = good.clone();
        outside["members"][0]["file"] = "../w.safetensors".into();
        refused(outside.to_string(), "not a file name");
        // Not an ensemble file at all, a NaN calibration, no members.
        refused(
            "{\"format\": 1}".into(),
            "not a fishprobe disagreement file",
        );
        let mut nan = good.clone();
        nan["raw_p95"] = serde_json::Value::Null;
        refused(nan.to_string(), "not a fishprobe disagreement file");
        let mut none = good;
        none["members"] = serde_json::json!([]);
        refused(none.to_string(), "further members");
        // No file: the error says how to make one.
        std::fs::remove_file(&path).unwrap();
        let e = Disagreement::load(&weights, "w", &sha(&weights))
            .unwrap_err()
            .to_string();
        assert!(e.contains("--members"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn calibration_and_refusals() {
        let arch = ConvNetArch::default();
        let mut rng = stream(2, "t", 0);
        let nets: Vec<ConvNet> = (0..3)
            .map(|_| ConvNet::new(arch.clone(), &mut rng))
            .collect();
        // A lone network is no ensemble; a count the file does not match is refused.
        assert!(Disagreement::new(vec![nets[0].clone()], file(0)).is_err());
        assert!(Disagreement::new(nets.clone(), file(1)).is_err());
        let views: Vec<f32> = (0..200 * arch.view_len())
            .map(|_| rng.random_range(0.0..1.0))
            .collect();
        let d = Disagreement::fit(nets.clone(), file(2), &views, 100, &mut rng).unwrap();
        assert!(d.file.raw_p95 > d.file.raw_median);
        assert_eq!(d.calibrate(d.file.raw_median), 0.0);
        assert!((d.calibrate(d.file.raw_p95) - 1.0).abs() < 1e-5);
        assert_eq!(d.calibrate(f32::NAN), 1e3);
        // Too few views to calibrate on.
        let few = &views[..10 * arch.view_len()];
        assert!(matches!(
            Disagreement::fit(nets, file(2), few, 100, &mut rng),
            Err(SupportError::TooFewViews { .. })
        ));
    }
}
