//! How the report is drawn. The paper does not prescribe any of this; each default is a
//! documented choice.

use fishprobe_sim::params::{check, ConfigError};

fishprobe_sim::documented_params! {
    /// Report settings.
    pub struct ReportConfig {
        /// Seconds of control drawn in the trajectory figure, from the start of control
        /// (choice: 120 s shows several goal runs without drowning them in 15 minutes of
        /// path).
        pub trajectory_seconds: f32 = 120.0; "s",
        /// Bin width of the inter-individual-distance densities before smoothing (choice).
        pub iid_bin_cm: f32 = 1.0; "cm",
        /// Standard deviation of the Gaussian kernel that smooths those densities (choice:
        /// 2 cm, a fifth of the robot's length).
        pub iid_kernel_cm: f32 = 2.0; "cm",
        /// Upper end of the distance axis; the tank's diagonal is 141 cm (choice).
        pub iid_max_cm: f32 = 100.0; "cm",
        /// Seconds per point of the approach assay's distance-over-time curves (choice).
        pub approach_bin_s: f32 = 1.0; "s",
        /// Device pixels per SVG pixel in the PNG files (choice: 2, sharp on slides).
        pub png_scale: f32 = 2.0; "1",
    }
}

/// Most bins of a distance density (`iid_max_cm / iid_bin_cm`): 2,000, a 0.05-cm bin over
/// the 100-cm axis. Each trial holds one histogram of this many bins, and smoothing costs
/// bins x kernel width per trial.
pub const MAX_IID_BINS: f32 = 2000.0;

impl ReportConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (f, v) in [
            ("trajectory_seconds", self.trajectory_seconds),
            ("approach_bin_s", self.approach_bin_s),
        ] {
            check::positive_at_most("report", f, v, check::MAX_DURATION_S)?;
        }
        check::positive_at_most(
            "report",
            "iid_max_cm",
            self.iid_max_cm,
            check::MAX_LENGTH_CM,
        )?;
        check::positive_at_most("report", "iid_bin_cm", self.iid_bin_cm, self.iid_max_cm)?;
        if self.iid_max_cm / self.iid_bin_cm > MAX_IID_BINS {
            return Err(ConfigError::new(
                "report",
                "iid_bin_cm",
                check::shown(self.iid_bin_cm),
                &format!(
                    "makes {} bins of the {}-cm axis (iid_max_cm); at most {} \
                     (fishprobe_report::config::MAX_IID_BINS)",
                    check::shown((self.iid_max_cm / self.iid_bin_cm).ceil()),
                    check::shown(self.iid_max_cm),
                    check::shown(MAX_IID_BINS)
                ),
            ));
        }
        // A kernel wider than the axis smooths every density flat.
        check::positive_at_most(
            "report",
            "iid_kernel_cm",
            self.iid_kernel_cm,
            self.iid_max_cm,
        )?;
        check::positive("report", "png_scale", self.png_scale)?;
        if self.png_scale > 8.0 {
            return Err(ConfigError::new(
                "report",
                "png_scale",
                check::shown(self.png_scale),
                "at most 8 (a larger PNG is not sharper on any screen)",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each of these made `fishprobe report --config` crash: an add overflow (trajectory),
    /// an 800-TB histogram (bin), a kernel of 1e30 bins (kernel).
    #[test]
    fn settings_that_crashed_the_report_are_refused_by_name() {
        assert!(ReportConfig::default().validate().is_ok());
        let cases: [(ReportConfig, &str, &str); 5] = [
            (
                ReportConfig {
                    trajectory_seconds: 1e30,
                    ..ReportConfig::default()
                },
                "report.trajectory_seconds",
                "(0, 86400]",
            ),
            (
                ReportConfig {
                    iid_bin_cm: 1e-12,
                    ..ReportConfig::default()
                },
                "report.iid_bin_cm",
                "makes 1e14 bins of the 100-cm axis",
            ),
            (
                ReportConfig {
                    iid_kernel_cm: 1e30,
                    ..ReportConfig::default()
                },
                "report.iid_kernel_cm",
                "(0, 100]",
            ),
            (
                ReportConfig {
                    iid_max_cm: 1e9,
                    ..ReportConfig::default()
                },
                "report.iid_max_cm",
                "(0, 1000]",
            ),
            (
                ReportConfig {
                    approach_bin_s: 1e30,
                    ..ReportConfig::default()
                },
                "report.approach_bin_s",
                "(0, 86400]",
            ),
        ];
        for (cfg, field, reason) in cases {
            let e = cfg.validate().unwrap_err().to_string();
            assert!(e.contains(field) && e.contains(reason), "{e}");
        }
        // The finest bin allowed on the default axis.
        let fine = ReportConfig {
            iid_bin_cm: 0.05,
            ..ReportConfig::default()
        };
        assert!(fine.validate().is_ok());
    }
}
