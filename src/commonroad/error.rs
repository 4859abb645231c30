//! The one error type of the facade crate's CommonRoad reader and writer.

use std::path::PathBuf;

/// Why a CommonRoad scenario could not be read or turned into a nudge scenario, or a
/// solution could not be written. Every variant names the file; those about one element
/// name its 1-based line.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CommonRoadError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// Not well-formed XML, not gzip, or not a CommonRoad document.
    #[error("{path}: line {line}: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// 1-based line of the problem (0 when unknown).
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// A required element or attribute is missing, not a number, or out of range.
    #[error("{path}: line {line}: <{element}>: {reason}")]
    Field {
        /// The file.
        path: PathBuf,
        /// 1-based line of the element (or its parent when it is missing).
        line: usize,
        /// The element or attribute, e.g. `obstacle 132 step 21 velocity`.
        element: String,
        /// What is wrong.
        reason: String,
    },
    /// The file exceeds one of the reader's budgets (decompressed size, nesting depth,
    /// element count, attributes per element): refused before the work or memory it would
    /// take.
    #[error("{path}: exceeds the {budget} budget of {limit}")]
    Budget {
        /// The file.
        path: PathBuf,
        /// Which budget.
        budget: XmlBudget,
        /// The budget's limit (bytes, levels or elements, as `budget` says).
        limit: u64,
    },
    /// A CommonRoad feature nudge does not handle (road shape, version, obstacle shape).
    #[error("{path}: not supported: {reason}")]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// What is not supported, with the measured value and the limit.
        reason: String,
    },
    /// The requested ego (obstacle or planning problem) cannot start a scenario at the
    /// requested time.
    #[error("{path}: {ego}: {reason}")]
    Ego {
        /// The file.
        path: PathBuf,
        /// `obstacle <id>` or `planning problem <id>`.
        ego: String,
        /// Why (unknown id, no history, too short a logged future, ...).
        reason: String,
    },
    /// A planning problem's goal cannot be planned to, or the closed loop did not reach it.
    #[error("{path}: planning problem {problem}: goal: {reason}")]
    Goal {
        /// The file.
        path: PathBuf,
        /// The planning problem's id.
        problem: i64,
        /// Why (a goal beyond the map, behind the ego, between lanes, a time window that has
        /// passed; or, after the run, how close the ego came).
        reason: String,
    },
    /// The scenario built from the file does not validate as a nudge scenario.
    #[error("{path}: the scenario built from it is not valid: {source}")]
    Scenario {
        /// The CommonRoad file.
        path: PathBuf,
        /// The nudge scenario reader's error.
        source: nudge_planner::ScenarioError,
    },
    /// A closed-loop record cannot be written as a solution (too few steps, non-finite state).
    #[error("solution for {path}: {reason}")]
    Solution {
        /// The CommonRoad scenario file the solution is for.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

/// The reader's budgets on one file ([`CommonRoadError::Budget`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum XmlBudget {
    /// Bytes of XML after decompression ([`super::xml::MAX_XML_BYTES`]).
    DecompressedBytes,
    /// Element nesting depth, the root being level 1 ([`super::xml::MAX_XML_DEPTH`]).
    Depth,
    /// Elements in the document ([`super::xml::MAX_XML_ELEMENTS`]).
    Elements,
    /// Attributes of one element ([`super::xml::MAX_XML_ATTRIBUTES`]).
    Attributes,
}

impl std::fmt::Display for XmlBudget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::DecompressedBytes => "decompressed-size (bytes)",
            Self::Depth => "nesting-depth (levels)",
            Self::Elements => "element-count (elements)",
            Self::Attributes => "attributes-per-element",
        })
    }
}
