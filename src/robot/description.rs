//! A robot description file, whichever machine it describes (docs/arms.md "One
//! description, two machines"): its top-level `kind` says how to read the rest.
//! `kind = "hybrid"` is the 3-UPS/UP parallel module with the 2R head
//! ([`Geometry`], assets/robot.toml); `kind = "serial"` is a serial arm in modified DH
//! form ([`Arm`], assets/arms/). A file without `kind` is a hybrid asset written before
//! the field existed. Every command that takes `--robot` reads it through here and runs
//! that machine's own chain.

use std::path::Path;

use super::arm::Arm;
use super::{read_description, Geometry, RobotError};

/// The kinds a description may declare.
pub const KINDS: [&str; 2] = ["hybrid", "serial"];

/// The machine a description file describes.
#[derive(Clone, Debug)]
pub enum Description {
    /// The hybrid polishing machine (`kind = "hybrid"` or no `kind`).
    Hybrid(Geometry),
    /// A serial arm (`kind = "serial"`).
    Serial(Arm),
}

impl Description {
    /// Reads and checks the description at `path`; errors name the file and the field.
    pub fn load(path: &Path) -> Result<Description, RobotError> {
        Description::parse(&read_description(path)?, &path.display().to_string())
    }

    /// The file at `path`, or the embedded hybrid asset when there is none.
    pub fn load_or_default(path: Option<&Path>) -> Result<Description, RobotError> {
        match path {
            Some(p) => Description::load(p),
            None => Ok(Description::Hybrid(Geometry::default_asset())),
        }
    }

    /// Parses a description (`file` names it in errors): `kind` picks the reader.
    ///
    /// ```
    /// use iastgcn::robot::Description;
    ///
    /// let hybrid = Description::parse(iastgcn::robot::DEFAULT_ASSET, "robot.toml")?;
    /// assert_eq!(hybrid.kind(), "hybrid");
    /// let err = Description::parse("kind = \"delta\"\n", "d.toml").unwrap_err();
    /// assert!(err.to_string().starts_with("d.toml: kind = \"delta\""));
    /// # Ok::<(), iastgcn::robot::RobotError>(())
    /// ```
    pub fn parse(text: &str, file: &str) -> Result<Description, RobotError> {
        let err = |message: String| RobotError::Asset {
            file: file.to_string(),
            message,
        };
        let table: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| err(e.to_string()))?;
        match table.get("kind") {
            None => Ok(Description::Hybrid(Geometry::parse(text, file)?)),
            Some(toml::Value::String(k)) if k == "hybrid" => {
                Ok(Description::Hybrid(Geometry::parse(text, file)?))
            }
            Some(toml::Value::String(k)) if k == "serial" => {
                Ok(Description::Serial(Arm::parse(text, file)?))
            }
            Some(other) => Err(err(format!(
                "kind = {other}: a robot description is kind = \"hybrid\" (the 3-UPS/UP + 2R \
                 polishing machine, assets/robot.toml) or kind = \"serial\" (a serial arm, \
                 docs/arms.md)"
            ))),
        }
    }

    /// `hybrid` or `serial`.
    pub fn kind(&self) -> &'static str {
        match self {
            Description::Hybrid(_) => KINDS[0],
            Description::Serial(_) => KINDS[1],
        }
    }
}
