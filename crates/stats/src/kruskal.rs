//! The Kruskal-Wallis H test with tie correction, as `scipy.stats.kruskal`.

use crate::error::{check_sample, StatsError};
use crate::special::chi2_sf;

/// H statistic and its p-value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kruskal {
    /// The tie-corrected H statistic.
    pub h: f64,
    /// P-value from the χ² distribution with k - 1 degrees of freedom.
    pub p: f64,
}

/// Kruskal-Wallis across `groups` (at least two, each non-empty).
pub fn kruskal(groups: &[&[f64]]) -> Result<Kruskal, StatsError> {
    if groups.len() < 2 {
        return Err(StatsError::Undefined(
            "kruskal needs at least two groups".into(),
        ));
    }
    let mut all: Vec<(f64, usize)> = Vec::new();
    for (g, x) in groups.iter().enumerate() {
        check_sample("kruskal group", x)?;
        all.extend(x.iter().map(|&v| (v, g)));
    }
    all.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n = all.len() as f64;
    let mut rank_sums = vec![0.0; groups.len()];
    let mut ties = 0.0;
    let mut i = 0;
    while i < all.len() {
        let mut j = i;
        while j + 1 < all.len() && all[j + 1].0 == all[i].0 {
            j += 1;
        }
        // Average rank of the tied block (ranks are 1-based).
        let rank = (i + j) as f64 / 2.0 + 1.0;
        for item in &all[i..=j] {
            rank_sums[item.1] += rank;
        }
        let t = (j - i + 1) as f64;
        ties += t * t * t - t;
        i = j + 1;
    }
    let h0 = 12.0 / (n * (n + 1.0))
        * groups
            .iter()
            .zip(&rank_sums)
            .map(|(g, r)| r * r / g.len() as f64)
            .sum::<f64>()
        - 3.0 * (n + 1.0);
    let correction = 1.0 - ties / (n * n * n - n);
    if correction <= 0.0 {
        return Err(StatsError::Undefined(
            "kruskal: all values are identical".into(),
        ));
    }
    let h = h0 / correction;
    Ok(Kruskal {
        h,
        p: chi2_sf(h, (groups.len() - 1) as f64),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_scipy() {
        // scipy.stats.kruskal(g1, g2, g3, g4) with ties
        let g1 = [3.0, 5.0, 5.0, 7.0, 9.0, 2.0];
        let g2 = [5.0, 6.0, 8.0, 8.0, 10.0];
        let g3 = [1.0, 2.0, 2.0, 3.0, 5.0, 5.0, 4.0];
        let g4 = [7.0, 8.0, 9.0, 9.0, 12.0];
        let k = kruskal(&[&g1, &g2, &g3, &g4]).unwrap();
        assert!((k.h - 13.413_208_901_651_11).abs() < 1e-10, "{}", k.h);
        assert!((k.p - 0.003_823_122_592_767_835_7).abs() < 1e-12, "{}", k.p);
        let k = kruskal(&[&[1.5, 2.5, 3.1], &[2.0, 4.0, 5.0, 6.0]]).unwrap();
        assert!((k.h - 2.0).abs() < 1e-12);
        assert!((k.p - 0.157_299_207_050_281_53).abs() < 1e-12);
        assert!(kruskal(&[&[1.0, 1.0], &[1.0]]).is_err());
        assert!(kruskal(&[&[1.0, 2.0]]).is_err());
    }
}
