use super::*;
use crate::convnet::{encode_view, ConvNetArch};
use fishprobe_sim::{stream, AgentState, SimRng, Tank, TankParams};
use rand::RngExt;
use std::f32::consts::PI;

fn views_of(pairs: &[(AgentState, AgentState)], arch: &ConvNetArch, tank: &Tank) -> Vec<f32> {
    let mut out = Vec::new();
    let mut v = vec![0.0; arch.view_len()];
    for (a, b) in pairs {
        encode_view(arch, tank, a, &[*b], &mut v);
        out.extend_from_slice(&v);
    }
    out
}

/// Followers: a partner 3-10 cm behind-left, swimming the same way, in the tank's middle.
fn follower_views(n: usize, rng: &mut SimRng) -> Vec<(AgentState, AgentState)> {
    (0..n)
        .map(|_| {
            let me = AgentState::at(
                rng.random_range(-25.0..25.0),
                rng.random_range(-25.0..25.0),
                rng.random_range(-PI..PI),
            );
            let b = me.heading + 2.5 + rng.random_range(-0.3..0.3);
            let d = rng.random_range(3.0..10.0);
            let o = AgentState::at(me.x + d * b.cos(), me.y + d * b.sin(), me.heading);
            (me, o)
        })
        .collect()
}

#[test]
fn a_view_shows_its_situation() {
    let arch = ConvNetArch::default();
    let tank = Tank::new(&TankParams::default());
    // Facing +x at (40, 0): the wall 9.5 cm ahead (50 - 0.5 margin? raycast to the wall).
    let me = AgentState::at(40.0, 0.0, 0.0);
    let other = AgentState::at(30.0, 0.0, 0.0); // 10 cm behind, same heading
    let mut v = vec![0.0; arch.view_len()];
    encode_view(&arch, &tank, &me, &[other], &mut v);
    let s = Situation::of_view(&arch, &v);
    assert!((s.partner_distance_cm - 10.0).abs() < 0.01, "{s:?}");
    // Behind: the bin centred 2.5° from ±180°.
    assert!(s.partner_bearing_rad.abs() > PI - 0.05, "{s:?}");
    assert!(s.relative_heading_rad.abs() < 1e-6, "{s:?}");
    let wall_ahead = tank.raycast(40.0, 0.0, 1.0, 0.0);
    // The nearest ray is one of the two bins either side of straight ahead.
    assert!(
        (s.wall_distance_cm - wall_ahead).abs() < 0.05,
        "{s:?} vs {wall_ahead}"
    );
    assert!(s.wall_bearing_rad.abs() < 0.05, "{s:?}");
    // Along the right wall the second wall (≥ 80° away) is 10 cm / cos 80°, or the
    // top/bottom wall's 49.5 cm: whichever ray of those bins is shortest.
    assert!(s.second_wall_cm > 40.0, "{s:?}");
    // In the corner (48, 48) facing +x: the top wall is 90° away, about as near.
    encode_view(
        &arch,
        &tank,
        &AgentState::at(48.0, 48.0, 0.0),
        &[other],
        &mut v,
    );
    let c = Situation::of_view(&arch, &v);
    assert!(c.second_wall_cm < 2.5, "{c:?}");
    assert!(c.describe().contains("in a corner"), "{}", c.describe());
    assert!(s.describe().contains("behind"), "{}", s.describe());
    assert!(s.describe().contains("same way"), "{}", s.describe());
}

#[test]
fn both_estimators_score_training_like_views_low_and_unseen_situations_high() {
    let arch = ConvNetArch::default();
    let tank = Tank::new(&TankParams::default());
    let mut rng = stream(3, "support-test", 0);
    let train = views_of(&follower_views(3000, &mut rng), &arch, &tank);
    let held_out = views_of(&follower_views(500, &mut rng), &arch, &tank);
    let synthetic = synthetic_views(&arch, &tank, 300, &mut rng);
    for est in [Estimator::Knn, Estimator::Gmm] {
        let cfg = SupportConfig {
            estimator: est,
            reference_views: 1500,
            calibration_views: 1000,
            components: 8,
            em_iterations: 40,
            ..Default::default()
        };
        let s = SupportModel::fit(&arch, &train, &cfg, "test", "", &mut rng).unwrap();
        let scores = |v: &[f32]| -> Vec<f32> {
            v.chunks_exact(arch.view_len())
                .map(|x| s.score_view(x))
                .collect()
        };
        let inside = scores(&held_out);
        let within = inside.iter().filter(|&&x| x <= 1.0).count() as f32 / 500.0;
        assert!((0.88..=0.99).contains(&within), "{est:?}: {within}");
        for (kind, v) in &synthetic {
            let out = scores(v);
            let a = auc(&inside, &out);
            assert!(a > 0.95, "{est:?} {kind}: AUC {a}");
            let beyond = out.iter().filter(|&&x| x > 1.0).count() as f32 / 300.0;
            assert!(beyond > 0.8, "{est:?} {kind}: {beyond}");
        }
        // The file round-trips, and checks what it belongs to.
        let dir = std::env::temp_dir().join(format!("fp-support-{}-{est:?}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut named = s.clone();
        named.model_sha256 = "abc".into();
        let p = dir.join("m.support.json");
        named.save(&p).unwrap();
        let back = SupportModel::load(&p, "m", "abc").unwrap();
        assert_eq!(back, named);
        let e = SupportModel::load(&p, "m", "def").unwrap_err();
        assert!(matches!(e, SupportError::OtherModel { .. }), "{e}");
        let e = SupportModel::load(&dir.join("none.json"), "m", "").unwrap_err();
        assert!(e.to_string().contains("fit-convnet"), "{e}");
        std::fs::write(&p, "{\"format\": 3}").unwrap();
        let e = SupportModel::load(&p, "m", "").unwrap_err();
        assert!(
            e.to_string().contains("not a fishprobe support file"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}

#[test]
fn the_shipped_convnet_has_its_support_and_other_models_have_none() {
    let s = crate::ModelSpec::by_name("ConvNet")
        .unwrap()
        .support()
        .unwrap();
    assert_eq!(s.model_sha256, crate::convnet::shipped_sha256());
    assert_eq!(s.config.estimator, Estimator::Knn);
    assert!(s.points.len() >= 1000, "{}", s.points.len());
    let e = crate::ModelSpec::by_name("Zone")
        .unwrap()
        .support()
        .unwrap_err();
    assert!(e.to_string().contains("not data-driven"), "{e}");
    let e = crate::ModelSpec::by_name("convnet:/nonexistent/w.safetensors")
        .unwrap()
        .support()
        .unwrap_err();
    assert!(e.to_string().contains("/nonexistent/w.safetensors"), "{e}");
}

#[test]
fn a_partner_range_embeds_far_partners_as_not_seen() {
    let arch = ConvNetArch::default();
    let tank = Tank::new(&TankParams::default());
    let me = AgentState::at(0.0, 0.0, 0.0);
    let mut v = vec![0.0; arch.view_len()];
    let sit = |d: f32, v: &mut Vec<f32>| {
        encode_view(&arch, &tank, &me, &[AgentState::at(0.0, d, PI)], v);
        Situation::of_view(&arch, v)
    };
    let near = sit(8.0, &mut v);
    let far = sit(40.0, &mut v);
    // Within range, and with no range, nothing changes.
    assert_eq!(near.features_within(20.0), near.features());
    assert_eq!(far.features_within(0.0), far.features());
    // Beyond it: at the range, no bearing, no heading; the walls as they are.
    let f = far.features_within(20.0);
    assert!((f[0] - 20.0f32.ln_1p()).abs() < 1e-6, "{f:?}");
    assert_eq!(&f[1..5], &[0.0; 4]);
    assert_eq!(&f[5..], &far.features()[5..]);
    // Training data with the partner 3-10 cm away but now and then 30-45 cm, anywhere:
    // with no range every far partner in a new direction scores far out; with a range of
    // 20 cm the far partners all look alike and lie within the data.
    let mut rng = stream(5, "support-range", 0);
    let mut pairs = follower_views(2700, &mut rng);
    let far_pair = |rng: &mut SimRng| {
        let me = AgentState::at(
            rng.random_range(-5.0..5.0),
            rng.random_range(-5.0..5.0),
            rng.random_range(-PI..PI),
        );
        let b = rng.random_range(-PI..PI);
        let d = rng.random_range(30.0..42.0);
        let o = AgentState::at(
            me.x + d * b.cos(),
            me.y + d * b.sin(),
            rng.random_range(-PI..PI),
        );
        (me, o)
    };
    pairs.extend((0..300).map(|_| far_pair(&mut rng)));
    let train = views_of(&pairs, &arch, &tank);
    // Far partners ahead, heading at the fish: rare among 300 random far partners.
    let probe: Vec<(AgentState, AgentState)> = (0..200)
        .map(|_| {
            let me = AgentState::at(0.0, 0.0, rng.random_range(-PI..PI));
            let d = rng.random_range(30.0..42.0);
            let o = AgentState::at(d * me.heading.cos(), d * me.heading.sin(), me.heading + PI);
            (me, o)
        })
        .collect();
    let probe = views_of(&probe, &arch, &tank);
    let mean_score = |range: f32, rng: &mut SimRng| {
        let cfg = SupportConfig {
            reference_views: 1500,
            calibration_views: 1000,
            partner_range_cm: range,
            ..Default::default()
        };
        let s = SupportModel::fit(&arch, &train, &cfg, "test", "", rng).unwrap();
        let sc: Vec<f32> = probe
            .chunks_exact(arch.view_len())
            .map(|x| s.score_view(x))
            .collect();
        sc.iter().sum::<f32>() / sc.len() as f32
    };
    let open = mean_score(0.0, &mut rng);
    let ranged = mean_score(20.0, &mut rng);
    assert!(
        open > 1.0 && ranged < 0.5,
        "no range {open}, range 20 cm {ranged}"
    );
    let bad = SupportConfig {
        partner_range_cm: f32::NAN,
        ..Default::default()
    };
    let e = bad.validate().unwrap_err();
    assert!(e.to_string().contains("support.partner_range_cm"), "{e}");
    let absurd = SupportConfig {
        partner_range_cm: 1e30,
        ..Default::default()
    };
    let e = absurd.validate().unwrap_err();
    assert!(e.to_string().contains("[0, 1000]"), "{e}");
}

#[test]
fn the_auc_matches_hand_counts() {
    // Pairs (out > in): 3 > 1, 3 > 2, 2 = 2 (half), 1 = 1 (half) ... out {3, 2}, in {1, 2}:
    // (3>1) + (3>2) + (2>1) + 0.5 (2=2) = 3.5 of 4.
    assert!((auc(&[1.0, 2.0], &[3.0, 2.0]) - 0.875).abs() < 1e-12);
    assert!((auc(&[1.0, 1.0], &[1.0]) - 0.5).abs() < 1e-12);
    assert!((auc(&[5.0], &[1.0, 2.0]) - 0.0).abs() < 1e-12);
}

#[test]
fn bad_settings_and_too_little_data_are_refused() {
    let arch = ConvNetArch::default();
    let mut rng = stream(1, "t", 0);
    let cfg = SupportConfig {
        neighbours: 0,
        ..Default::default()
    };
    let e = SupportModel::fit(&arch, &[], &cfg, "m", "", &mut rng).unwrap_err();
    assert!(e.to_string().contains("support.neighbours"), "{e}");
    let e = SupportModel::fit(
        &arch,
        &vec![0.0; arch.view_len() * 10],
        &SupportConfig::default(),
        "m",
        "",
        &mut rng,
    )
    .unwrap_err();
    assert!(
        matches!(e, SupportError::TooFewViews { got: 10, .. }),
        "{e}"
    );
}
