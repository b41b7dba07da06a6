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

impl ReportConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check::positive("report", "trajectory_seconds", self.trajectory_seconds)?;
        check::positive("report", "iid_bin_cm", self.iid_bin_cm)?;
        check::positive("report", "iid_kernel_cm", self.iid_kernel_cm)?;
        check::positive("report", "iid_max_cm", self.iid_max_cm)?;
        check::positive("report", "approach_bin_s", self.approach_bin_s)?;
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
