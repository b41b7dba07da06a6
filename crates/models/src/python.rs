//! A fish model written in Python: recorded here so that a run's `params.json` and its trial
//! files say what drove the fish, but built only by the `fishprobe` Python package, which
//! holds the Python object (`fishprobe.LeadToGoalEnv(model=MyFish())`, `fishprobe.train`).

use crate::{ModelError, ModelParams};
use fishprobe_sim::params::ConfigError;
use fishprobe_sim::FishModel;
use std::sync::Arc;

fishprobe_sim::documented_params! {
    /// A fish model written in Python (its class), driven by the `fishprobe` Python package.
    pub struct PythonParams {
        /// The model's class, as `module.QualifiedName`.
        pub class: String = String::new(); "-",
        /// The model's `name` (the class name unless it sets one): what reports call it.
        pub name: String = String::new(); "-",
    }
}

impl ModelParams for PythonParams {
    const NAME: &'static str = "Python";
    const SUMMARY: &'static str =
        "a fish model written in Python (a class with decide(views)), run by the Python package";

    fn check(&self, prefix: &str) -> Result<(), ConfigError> {
        if self.class.trim().is_empty() {
            return Err(ConfigError::new(
                prefix,
                "class",
                "\"\"",
                "must name the model's Python class",
            ));
        }
        Ok(())
    }

    fn build_model(&self) -> Result<Arc<dyn FishModel>, ModelError> {
        Err(ModelError::NeedsPython {
            class: self.class.clone(),
        })
    }
}

#[cfg(test)]
mod tests {
    use crate::{ModelError, ModelSpec, PythonParams};

    #[test]
    fn a_python_model_is_recorded_but_not_built_without_python() {
        let spec: ModelSpec =
            serde_json::from_str(r#"{"model": "Python", "class": "lab.MyFish", "name": "MyFish"}"#)
                .unwrap();
        assert_eq!(spec.label(), "MyFish");
        assert_eq!(spec.origin(), "Python class lab.MyFish");
        assert!(!ModelSpec::NAMES.contains(&"Python"));
        let err = spec.build().unwrap_err();
        assert!(matches!(err, ModelError::NeedsPython { .. }));
        assert!(err.to_string().contains("lab.MyFish"), "{err}");
        let empty = ModelSpec::Python(PythonParams::default());
        assert!(empty.validate().unwrap_err().to_string().contains("class"));
    }
}
