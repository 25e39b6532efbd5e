//! Scene files (TOML) to a compiled [`System`] plus run defaults, with every error located by
//! file, line and column (and, inside expressions, a caret under the offending text).
//! (Skeleton: to be implemented.)

use std::path::Path;
use std::sync::Arc;

use crate::formulation::{Feedback, Method};
use crate::integrate::IntegratorKind;
use crate::model::System;

/// A loaded scene.
#[derive(Clone, Debug)]
pub struct Scene {
    pub title: String,
    /// The file name as given (for messages and summaries).
    pub file: String,
    pub system: Arc<System>,
    /// Parameter values after overrides, in file order.
    pub params: Vec<(String, f64)>,
    /// The `[run]` table.
    pub run: RunDefaults,
}

/// `[run]` defaults; every field may be overridden on the command line.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunDefaults {
    pub method: Option<Method>,
    pub integrator: Option<IntegratorKind>,
    pub dt: Option<f64>,
    pub duration: Option<f64>,
    pub steps: Option<u64>,
    pub stabilize: Option<Feedback>,
}

/// A scene that cannot be loaded: what and where.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{}", self.render())]
pub struct SceneError {
    pub file: String,
    /// 1-based; 0 when the error has no position (e.g. the file cannot be read).
    pub line: usize,
    /// 1-based, in characters.
    pub column: usize,
    pub message: String,
    /// Source line(s) with a caret under the offending text, when known.
    pub snippet: Option<String>,
}

impl SceneError {
    /// `file:line:column: message` followed by the snippet.
    pub fn render(&self) -> String {
        todo!()
    }
}

impl Scene {
    /// Read and load a scene file; `overrides` replace `[params]` values (`--set NAME=VALUE`;
    /// an unknown name is an error).
    pub fn load(path: &Path, overrides: &[(String, f64)]) -> Result<Scene, SceneError> {
        let _ = (path, overrides);
        todo!()
    }

    /// Load a scene from text; `file` names it in messages.
    pub fn parse(text: &str, file: &str, overrides: &[(String, f64)]) -> Result<Scene, SceneError> {
        let _ = (text, file, overrides);
        todo!()
    }

    /// Warnings about the scene that do not stop a run, e.g. a parametric initial state that
    /// does not reproduce the particles' positions and velocities.
    pub fn warnings(&self) -> Vec<String> {
        todo!()
    }
}
