//! CommonRoad in and out: read a CommonRoad 2020a (or 2018b) scenario file (`.xml` or
//! `.xml.gz`) into the road frame nudge plans in, build the nudge scenario of one ego (a
//! dynamic obstacle or a planning problem) at one time, and write a closed-loop run's executed
//! ego trajectory as a CommonRoad solution in the scenario's own coordinates.
//!
//! The road frame is the data pipeline's (`nudge_train.data.commonroad`): the scene rotated so
//! that traffic runs along +x and straightened along a polynomial fitted to the lanelet bounds
//! ([`frame`]); lanes are lines y = const ([`lanes`]). Where the lanes near the ego are not
//! straight within [`scene::STRAIGHT_TOL`] there, the scene is planned in the curvilinear
//! (Frenet) frame along a spline reference path instead ([`frenet`],
//! [`CommonRoadScene::prepare`]); what that frame cannot represent either is refused with
//! [`CommonRoadError::Unsupported`] naming the file and the reason. A planning problem's goal
//! ([`goal`]) sets the run's target lane, its timing and where its solution ends.
//!
//! ```no_run
//! use nudge::commonroad::{CommonRoadScene, Ego};
//! # fn main() -> Result<(), nudge::commonroad::CommonRoadError> {
//! let scene = CommonRoadScene::read("USA_US101-11_1_T-1.xml.gz")?;
//! let ego = Ego::Obstacle(132);
//! let t0 = scene.default_t0(ego)?; // s: the first time with a full 2.1 s history
//! let scenario = scene.scenario(ego, t0)?;
//! assert_eq!(scenario.agent_ids[0], 132);
//! # Ok(()) }
//! ```

mod error;
pub mod frame;
pub mod frenet;
pub mod goal;
pub mod lanes;
pub mod scene;
pub mod solution;
pub mod xml;

pub use error::{CommonRoadError, XmlBudget};
pub use frame::RoadFrame;
pub use goal::{GoalPolicy, GoalShape, GoalState, Interval, RoadGoal};
pub use lanes::LaneMap;
pub use scene::{CommonRoadScene, Ego};
pub use solution::{Solution, VEHICLE};
pub use xml::RawScenario;
