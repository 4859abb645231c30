//! Reading a CommonRoad scenario file (`.xml`, or `.xml.gz`) into plain data: the lanelet
//! bounds, the dynamic obstacles' states and the planning problems' initial states, each value
//! checked (finite, in range) and named in errors by element and line.
//!
//! Formats: 2020a (`<dynamicObstacle>`) and 2018b (`<obstacle>` with `<role>dynamic</role>`),
//! as the data pipeline's reader (`nudge_train.data.commonroad`) accepts.

use std::io::Read;
use std::path::{Path, PathBuf};

use quick_xml::events::{BytesRef, BytesStart, Event};

use super::error::{CommonRoadError, XmlBudget};
use super::goal::{GoalShape, GoalState, Interval};

/// Largest CommonRoad file read (bytes, after decompression): 32 MiB, 12 times the largest
/// US-101 scene (2.6 MB). The gzip stream is inflated through a bounded reader, so a small
/// file that inflates further is refused after this many bytes.
pub const MAX_XML_BYTES: u64 = 32 << 20;
/// Deepest element nesting accepted (levels, the root is 1): CommonRoad documents nest 7
/// deep (`commonRoad/dynamicObstacle/trajectory/state/position/point/x`).
pub const MAX_XML_DEPTH: usize = 64;
/// Most elements accepted in one document: 1,000,000, 13 times the largest US-101 scene
/// (76,753). Each element costs about 200 bytes in the tree, so this bounds it near 200 MB.
pub const MAX_XML_ELEMENTS: usize = 1_000_000;
/// Most attributes of one element: CommonRoad elements carry at most a handful (`commonRoad`
/// has 7). The XML library checks each attribute's name against the element's earlier ones,
/// so the work grows with the square of their number: a million-attribute element would take
/// hours.
pub const MAX_XML_ATTRIBUTES: usize = 64;
/// Largest |coordinate| accepted (m), as the pipeline's `COORD` rule.
pub const MAX_COORD: f64 = 1e5;
/// Largest |orientation| accepted (rad): 4π.
pub const MAX_ORIENTATION: f64 = 4.0 * std::f64::consts::PI;
/// Largest |velocity| accepted (m/s).
pub const MAX_VELOCITY: f64 = 300.0;
/// Largest vehicle length or width accepted (m); both must be > 0.
pub const MAX_SIZE: f64 = 100.0;
/// Largest time step index accepted.
pub const MAX_TIME_STEP: f64 = 1e7;
/// Largest `timeStepSize` accepted (s); it must be > 0.
pub const MAX_STEP_SIZE: f64 = 60.0;

/// One XML element: name, attributes, text, children and its 1-based line.
#[derive(Debug, Default)]
pub(crate) struct Node {
    name: String,
    attrs: Vec<(String, String)>,
    text: String,
    children: Vec<Node>,
    line: usize,
}

impl Node {
    fn child(&self, name: &str) -> Option<&Node> {
        self.children.iter().find(|c| c.name == name)
    }

    /// The first descendant along `path` (`a/b/c`).
    fn find(&self, path: &str) -> Option<&Node> {
        path.split('/').try_fold(self, |n, p| n.child(p))
    }

    fn children<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Node> + 'a {
        self.children.iter().filter(move |c| c.name == name)
    }

    fn attr(&self, key: &str) -> Option<&str> {
        self.attrs
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
}

/// One vehicle state (CommonRoad's own frame): time step, centre (m), orientation (rad),
/// speed (m/s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawState {
    /// Time step index (time = step · `dt`).
    pub step: i64,
    /// Centre x (m).
    pub x: f64,
    /// Centre y (m).
    pub y: f64,
    /// Orientation (rad, 0 = +x of the file's frame).
    pub orientation: f64,
    /// Speed (m/s).
    pub velocity: f64,
}

/// One lanelet: id, line, left and right bounds (`[P, 2]` points each, m).
#[derive(Debug, Clone, PartialEq)]
pub struct RawLanelet {
    /// The lanelet's `id`.
    pub id: String,
    /// 1-based line of `<lanelet>`.
    pub line: usize,
    /// Left bound points (m).
    pub left: Vec<[f64; 2]>,
    /// Right bound points (m).
    pub right: Vec<[f64; 2]>,
}

/// One dynamic obstacle: id, rectangle (length, width) (m) and its states in time order.
#[derive(Debug, Clone, PartialEq)]
pub struct RawObstacle {
    /// The obstacle's `id`.
    pub id: i64,
    /// 1-based line of the obstacle element.
    pub line: usize,
    /// Rectangle length (m).
    pub length: f64,
    /// Rectangle width (m).
    pub width: f64,
    /// Initial state then the trajectory, strictly increasing steps.
    pub states: Vec<RawState>,
}

/// One planning problem: id, initial state and goal states.
#[derive(Debug, Clone, PartialEq)]
pub struct RawPlanningProblem {
    /// The planning problem's `id`.
    pub id: i64,
    /// 1-based line of `<planningProblem>`.
    pub line: usize,
    /// Its initial state.
    pub initial: RawState,
    /// Its goal states (`<goalState>`, in file order; reaching any one reaches the goal).
    pub goals: Vec<GoalState>,
}

/// What nudge reads of one CommonRoad scenario file.
#[derive(Debug, Clone, PartialEq)]
pub struct RawScenario {
    /// The file.
    pub path: PathBuf,
    /// `commonRoadVersion` (`2020a` or `2018b`).
    pub version: String,
    /// `benchmarkID` (the file stem when absent).
    pub benchmark_id: String,
    /// `timeStepSize` (s).
    pub dt: f64,
    /// The lanelets, in file order.
    pub lanelets: Vec<RawLanelet>,
    /// The dynamic obstacles, in file order.
    pub obstacles: Vec<RawObstacle>,
    /// The planning problems, in file order.
    pub planning_problems: Vec<RawPlanningProblem>,
}

/// The file's text: gunzipped when it starts with the gzip magic bytes. Only regular files
/// of at most [`MAX_XML_BYTES`] are read (a FIFO or device is refused before reading), and
/// the gzip stream is inflated through a reader that stops after [`MAX_XML_BYTES`] + 1 bytes.
fn read_text(path: &Path) -> Result<String, CommonRoadError> {
    let too_big = || CommonRoadError::Budget {
        path: path.to_path_buf(),
        budget: XmlBudget::DecompressedBytes,
        limit: MAX_XML_BYTES,
    };
    let raw = nudge_predictor::file::read_bounded(path, MAX_XML_BYTES).map_err(|e| match e {
        nudge_predictor::PredictorError::Io { path, source } => {
            CommonRoadError::Io { path, source }
        }
        nudge_predictor::PredictorError::FileTooLarge { .. } => too_big(),
        other => format_error(path, 0, other.to_string()),
    })?;
    let bytes = if raw.starts_with(&[0x1f, 0x8b]) {
        let mut out = Vec::new();
        flate2::read::MultiGzDecoder::new(raw.as_slice())
            .take(MAX_XML_BYTES + 1)
            .read_to_end(&mut out)
            .map_err(|e| format_error(path, 0, format!("not valid gzip: {e}")))?;
        out
    } else {
        raw
    };
    if bytes.len() as u64 > MAX_XML_BYTES {
        return Err(too_big());
    }
    String::from_utf8(bytes).map_err(|e| format_error(path, 0, format!("not UTF-8: {e}")))
}

/// Whether `c` is an XML 1.0 `Char` (production \[2\]): the characters a character
/// reference may name (well-formedness constraint "Legal Character").
fn is_xml_char(c: char) -> bool {
    matches!(c, '\u{9}' | '\u{A}' | '\u{D}' | '\u{20}'..='\u{D7FF}' | '\u{E000}'..='\u{FFFD}' | '\u{10000}'..)
}

/// The text a general reference `&name;` in content stands for: a character reference
/// (`&#48;`, `&#x30;`) naming a legal XML character, or one of the five predefined entities.
/// Any other entity is refused: the reader does not expand entities declared in a DTD (the
/// CommonRoad schema declares none), so such a reference cannot be read correctly.
fn resolve_reference(
    r: &BytesRef<'_>,
    path: &Path,
    line: usize,
) -> Result<String, CommonRoadError> {
    let name = r
        .decode()
        .map_err(|e| format_error(path, line, format!("bad reference: {e}")))?;
    if r.is_char_ref() {
        return match r.resolve_char_ref() {
            Ok(Some(c)) if is_xml_char(c) => Ok(c.to_string()),
            Ok(_) => Err(format_error(
                path,
                line,
                format!("character reference &{name}; names no legal XML character"),
            )),
            Err(e) => Err(format_error(
                path,
                line,
                format!("bad character reference &{name};: {e}"),
            )),
        };
    }
    quick_xml::escape::resolve_xml_entity(&name)
        .map(str::to_string)
        .ok_or_else(|| {
            format_error(
                path,
                line,
                format!("undefined entity &{name}; (only character references and the five predefined entities are read)"),
            )
        })
}

fn format_error(path: &Path, line: usize, reason: String) -> CommonRoadError {
    CommonRoadError::Format {
        path: path.to_path_buf(),
        line,
        reason,
    }
}

/// A node for the start tag `e` at `line`.
fn open(e: &BytesStart<'_>, line: usize, path: &Path) -> Result<Node, CommonRoadError> {
    let mut node = Node {
        name: String::from_utf8_lossy(e.name().as_ref()).into_owned(),
        line,
        ..Node::default()
    };
    for (k, a) in e.attributes().enumerate() {
        if k >= MAX_XML_ATTRIBUTES {
            return Err(CommonRoadError::Budget {
                path: path.to_path_buf(),
                budget: XmlBudget::Attributes,
                limit: MAX_XML_ATTRIBUTES as u64,
            });
        }
        let a = a.map_err(|err| format_error(path, line, format!("bad attribute: {err}")))?;
        let value = a
            .unescape_value()
            .map_err(|err| format_error(path, line, format!("bad attribute value: {err}")))?;
        node.attrs.push((
            String::from_utf8_lossy(a.key.as_ref()).into_owned(),
            value.into_owned(),
        ));
    }
    Ok(node)
}

/// Parses `text` into its root element, within the depth and element budgets
/// ([`MAX_XML_DEPTH`], [`MAX_XML_ELEMENTS`]). Text is the element's character data with its
/// character and predefined entity references decoded and CDATA sections included; an
/// undefined entity is refused ([`resolve_reference`]).
pub(crate) fn parse_tree(text: &str, path: &Path) -> Result<Node, CommonRoadError> {
    let mut reader = quick_xml::Reader::from_str(text);
    let mut stack: Vec<Node> = vec![Node::default()];
    let (mut seen, mut line, mut elements) = (0usize, 1usize, 0usize);
    let budget = |budget: XmlBudget, limit: usize| CommonRoadError::Budget {
        path: path.to_path_buf(),
        budget,
        limit: limit as u64,
    };
    loop {
        let pos = usize::try_from(reader.buffer_position()).unwrap_or(usize::MAX);
        let upto = pos.min(text.len());
        line += text.as_bytes()[seen.min(upto)..upto]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        seen = upto;
        let event = reader
            .read_event()
            .map_err(|e| format_error(path, line, format!("not valid XML: {e}")))?;
        let top = stack.len() - 1;
        if matches!(event, Event::Start(_) | Event::Empty(_)) {
            // `stack` holds the document node and the open ancestors: the new element's
            // level (the root being 1) is `stack.len()`.
            if stack.len() > MAX_XML_DEPTH {
                return Err(budget(XmlBudget::Depth, MAX_XML_DEPTH));
            }
            elements += 1;
            if elements > MAX_XML_ELEMENTS {
                return Err(budget(XmlBudget::Elements, MAX_XML_ELEMENTS));
            }
        }
        match event {
            Event::Start(e) => stack.push(open(&e, line, path)?),
            Event::Empty(e) => {
                let node = open(&e, line, path)?;
                stack[top].children.push(node);
            }
            Event::End(_) => {
                let node = stack.pop().filter(|_| top > 0).ok_or_else(|| {
                    format_error(path, line, "closing tag without an opening one".into())
                })?;
                stack[top - 1].children.push(node);
            }
            Event::Text(t) => stack[top].text.push_str(
                &t.xml_content()
                    .map_err(|e| format_error(path, line, format!("bad text: {e}")))?,
            ),
            Event::CData(t) => stack[top].text.push_str(
                &t.decode()
                    .map_err(|e| format_error(path, line, format!("bad CDATA: {e}")))?,
            ),
            Event::GeneralRef(r) => {
                let s = resolve_reference(&r, path, line)?;
                stack[top].text.push_str(&s);
            }
            Event::Eof => break,
            _ => {}
        }
    }
    let mut doc = stack
        .pop()
        .filter(|_| stack.is_empty())
        .ok_or_else(|| format_error(path, line, "the document ends inside an element".into()))?;
    doc.children
        .pop()
        .ok_or_else(|| format_error(path, line, "empty document".into()))
}

/// A range a number must lie in: `lo` (exclusive when `lo_open`) ..= `hi`.
#[derive(Debug, Clone, Copy)]
struct Range {
    lo: f64,
    hi: f64,
    lo_open: bool,
}

impl Range {
    const fn closed(lo: f64, hi: f64) -> Self {
        Self {
            lo,
            hi,
            lo_open: false,
        }
    }

    fn admits(self, v: f64) -> bool {
        v <= self.hi && (v > self.lo || (!self.lo_open && v >= self.lo))
    }
}

const COORD: Range = Range::closed(-MAX_COORD, MAX_COORD);
const ORIENTATION: Range = Range::closed(-MAX_ORIENTATION, MAX_ORIENTATION);
const VELOCITY: Range = Range::closed(-MAX_VELOCITY, MAX_VELOCITY);
const SIZE: Range = Range {
    lo: 0.0,
    hi: MAX_SIZE,
    lo_open: true,
};
const TIME_STEP: Range = Range::closed(0.0, MAX_TIME_STEP);
const STEP_SIZE: Range = Range {
    lo: 0.0,
    hi: MAX_STEP_SIZE,
    lo_open: true,
};

/// Reads values under one parent element, naming them in errors.
struct Fields<'a> {
    path: &'a Path,
}

impl Fields<'_> {
    fn err(&self, line: usize, element: &str, reason: String) -> CommonRoadError {
        CommonRoadError::Field {
            path: self.path.to_path_buf(),
            line,
            element: element.to_string(),
            reason,
        }
    }

    /// The number in `parent/sub`, finite and in `range`.
    fn num(
        &self,
        parent: &Node,
        sub: &str,
        what: &str,
        range: Range,
    ) -> Result<f64, CommonRoadError> {
        let node = parent
            .find(sub)
            .ok_or_else(|| self.err(parent.line, what, format!("missing <{sub}>")))?;
        self.value(node.text.trim(), node.line, what, range)
    }

    fn value(
        &self,
        tok: &str,
        line: usize,
        what: &str,
        range: Range,
    ) -> Result<f64, CommonRoadError> {
        let v: f64 = tok
            .parse()
            .map_err(|_| self.err(line, what, format!("not a number: {tok:?}")))?;
        if !v.is_finite() {
            return Err(self.err(line, what, format!("not finite: {tok:?}")));
        }
        if !range.admits(v) {
            let open = if range.lo_open { "(" } else { "[" };
            return Err(self.err(
                line,
                what,
                format!("{tok} outside {open}{}, {}]", range.lo, range.hi),
            ));
        }
        Ok(v)
    }

    fn integer(
        &self,
        tok: &str,
        line: usize,
        what: &str,
        range: Range,
    ) -> Result<i64, CommonRoadError> {
        let v = self.value(tok, line, what, range)?;
        if v.fract() != 0.0 {
            return Err(self.err(line, what, format!("{tok:?} is not an integer")));
        }
        #[allow(clippy::cast_possible_truncation)]
        Ok(v as i64)
    }

    fn points(
        &self,
        bound: Option<&Node>,
        ll: &Node,
        id: &str,
        side: &str,
    ) -> Result<Vec<[f64; 2]>, CommonRoadError> {
        let what = format!("lanelet {id} {side}");
        let bound = bound.ok_or_else(|| self.err(ll.line, &what, "missing bound".into()))?;
        self.point_list(bound, &what, 2)
    }

    /// The `point` children (x, y) of `node` (m), at least `min` of them; `what` names them in
    /// errors.
    fn point_list(
        &self,
        node: &Node,
        what: &str,
        min: usize,
    ) -> Result<Vec<[f64; 2]>, CommonRoadError> {
        let pts = node
            .children("point")
            .map(|p| {
                Ok([
                    self.num(p, "x", &format!("{what} x"), COORD)?,
                    self.num(p, "y", &format!("{what} y"), COORD)?,
                ])
            })
            .collect::<Result<Vec<_>, CommonRoadError>>()?;
        if pts.len() < min {
            return Err(self.err(node.line, what, format!("fewer than {min} points")));
        }
        Ok(pts)
    }

    fn lanelet(&self, ll: &Node) -> Result<RawLanelet, CommonRoadError> {
        let id = ll.attr("id").unwrap_or("?").to_string();
        Ok(RawLanelet {
            left: self.points(ll.child("leftBound"), ll, &id, "leftBound")?,
            right: self.points(ll.child("rightBound"), ll, &id, "rightBound")?,
            id,
            line: ll.line,
        })
    }

    /// One state element (`initialState` or `state`) of `who`.
    fn state(&self, st: &Node, who: &str) -> Result<RawState, CommonRoadError> {
        let te = st.find("time/exact").ok_or_else(|| {
            self.err(
                st.line,
                &format!("{who} time"),
                "missing <time><exact>".into(),
            )
        })?;
        let step = self.integer(te.text.trim(), te.line, &format!("{who} time"), TIME_STEP)?;
        let at = |f: &str| format!("{who} step {step} {f}");
        Ok(RawState {
            step,
            x: self.num(st, "position/point/x", &at("x"), COORD)?,
            y: self.num(st, "position/point/y", &at("y"), COORD)?,
            orientation: self.num(st, "orientation/exact", &at("orientation"), ORIENTATION)?,
            velocity: self.num(st, "velocity/exact", &at("velocity"), VELOCITY)?,
        })
    }

    fn obstacle(&self, ob: &Node) -> Result<RawObstacle, CommonRoadError> {
        let tok = ob.attr("id").unwrap_or("").trim();
        let id = self.integer(tok, ob.line, "obstacle id", Range::closed(0.0, 1e9))?;
        let who = format!("obstacle {id}");
        let rect = ob.find("shape/rectangle").ok_or_else(|| {
            self.err(
                ob.line,
                &format!("{who} shape"),
                "no rectangle shape".into(),
            )
        })?;
        let init = ob
            .child("initialState")
            .ok_or_else(|| self.err(ob.line, &format!("{who} initialState"), "missing".into()))?;
        let mut states = vec![self.state(init, &who)?];
        for st in ob
            .find("trajectory")
            .into_iter()
            .flat_map(|t| t.children("state"))
        {
            let s = self.state(st, &who)?;
            let last = states[states.len() - 1].step;
            if s.step <= last {
                return Err(self.err(
                    st.line,
                    &format!("{who} time"),
                    format!("non-monotonic time (step {} after {last})", s.step),
                ));
            }
            states.push(s);
        }
        Ok(RawObstacle {
            id,
            line: ob.line,
            length: self.num(rect, "length", &format!("{who} length"), SIZE)?,
            width: self.num(rect, "width", &format!("{who} width"), SIZE)?,
            states,
        })
    }

    fn planning_problem(
        &self,
        pp: &Node,
        lanelets: &[RawLanelet],
    ) -> Result<RawPlanningProblem, CommonRoadError> {
        let tok = pp.attr("id").unwrap_or("").trim();
        let id = self.integer(tok, pp.line, "planningProblem id", Range::closed(0.0, 1e9))?;
        let who = format!("planning problem {id}");
        let init = pp
            .child("initialState")
            .ok_or_else(|| self.err(pp.line, &format!("{who} initialState"), "missing".into()))?;
        let goals = pp
            .children("goalState")
            .enumerate()
            .map(|(k, g)| self.goal(g, &format!("{who} goal state {}", k + 1), lanelets))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(RawPlanningProblem {
            id,
            line: pp.line,
            initial: self.state(init, &who)?,
            goals,
        })
    }

    /// An interval element (`<intervalStart>`/`<intervalEnd>`, or `<exact>`) in `range`.
    fn interval(&self, node: &Node, what: &str, range: Range) -> Result<Interval, CommonRoadError> {
        if node.child("exact").is_some() {
            let v = self.num(node, "exact", what, range)?;
            return Ok(Interval { lo: v, hi: v });
        }
        let lo = self.num(
            node,
            "intervalStart",
            &format!("{what} intervalStart"),
            range,
        )?;
        let hi = self.num(node, "intervalEnd", &format!("{what} intervalEnd"), range)?;
        if hi < lo {
            return Err(self.err(
                node.line,
                what,
                format!("intervalEnd {hi} < intervalStart {lo}"),
            ));
        }
        Ok(Interval { lo, hi })
    }

    fn center(&self, shape: &Node, what: &str) -> Result<[f64; 2], CommonRoadError> {
        Ok([
            self.num(shape, "center/x", &format!("{what} center x"), COORD)?,
            self.num(shape, "center/y", &format!("{what} center y"), COORD)?,
        ])
    }

    /// The shapes (and lanelets) of a goal's `<position>`.
    fn goal_shapes(
        &self,
        pos: &Node,
        who: &str,
        lanelets: &[RawLanelet],
    ) -> Result<Vec<GoalShape>, CommonRoadError> {
        let mut shapes = Vec::new();
        for node in &pos.children {
            let what = format!("{who} position {}", node.name);
            let shape = match node.name.as_str() {
                "rectangle" => GoalShape::Rectangle {
                    length: self.num(node, "length", &format!("{what} length"), SIZE)?,
                    width: self.num(node, "width", &format!("{what} width"), SIZE)?,
                    orientation: match node.child("orientation") {
                        Some(_) => self.num(
                            node,
                            "orientation",
                            &format!("{what} orientation"),
                            ORIENTATION,
                        )?,
                        None => 0.0,
                    },
                    center: self.center(node, &what)?,
                },
                "circle" => GoalShape::Circle {
                    radius: self.num(node, "radius", &format!("{what} radius"), SIZE)?,
                    center: self.center(node, &what)?,
                },
                "polygon" => GoalShape::Polygon(self.point_list(node, &what, 3)?),
                "lanelet" => {
                    let r = node.attr("ref").unwrap_or("").trim();
                    GoalShape::lanelet(r, lanelets).ok_or_else(|| {
                        self.err(node.line, &what, format!("no lanelet with id {r:?}"))
                    })?
                }
                "point" => {
                    let p = [
                        self.num(node, "x", &format!("{what} x"), COORD)?,
                        self.num(node, "y", &format!("{what} y"), COORD)?,
                    ];
                    GoalShape::Circle {
                        radius: 0.0,
                        center: p,
                    }
                }
                other => {
                    return Err(CommonRoadError::Unsupported {
                        path: self.path.to_path_buf(),
                        reason: format!("line {}: {who}: goal position shape <{other}>", node.line),
                    });
                }
            };
            shapes.push(shape);
        }
        Ok(shapes)
    }

    /// One `<goalState>` of `who`.
    fn goal(
        &self,
        g: &Node,
        who: &str,
        lanelets: &[RawLanelet],
    ) -> Result<GoalState, CommonRoadError> {
        let time = g
            .child("time")
            .ok_or_else(|| self.err(g.line, &format!("{who} time"), "missing <time>".into()))?;
        let time = self.interval(time, &format!("{who} time"), TIME_STEP)?;
        let shapes = match g.child("position") {
            Some(p) => self.goal_shapes(p, who, lanelets)?,
            None => Vec::new(),
        };
        let velocity = g
            .child("velocity")
            .map(|v| self.interval(v, &format!("{who} velocity"), VELOCITY))
            .transpose()?;
        let orientation = g
            .child("orientation")
            .map(|o| self.interval(o, &format!("{who} orientation"), ORIENTATION))
            .transpose()?;
        Ok(GoalState {
            line: g.line,
            time,
            shapes,
            velocity,
            orientation,
        })
    }
}

/// The dynamic obstacles of `root` for `version`.
fn dynamic_obstacles<'a>(root: &'a Node, version: &str) -> Vec<&'a Node> {
    if version == "2020a" {
        root.children("dynamicObstacle").collect()
    } else {
        root.children("obstacle")
            .filter(|o| o.child("role").is_some_and(|r| r.text.trim() == "dynamic"))
            .collect()
    }
}

impl RawScenario {
    /// Reads the CommonRoad scenario file `path` (`.xml` or gzipped `.xml.gz`).
    ///
    /// # Errors
    /// [`CommonRoadError::Io`]; [`CommonRoadError::Format`] (not gzip/XML/CommonRoad, an
    /// unknown version, no lanelets, no dynamic obstacles);
    /// [`CommonRoadError::Field`] naming the element and line of a missing, non-numeric,
    /// non-finite or out-of-range value, a duplicate obstacle id or non-monotonic time.
    pub fn read(path: impl AsRef<Path>) -> Result<Self, CommonRoadError> {
        let path = path.as_ref();
        let root = parse_tree(&read_text(path)?, path)?;
        if root.name != "commonRoad" {
            let why = format!("root element <{}>, expected <commonRoad>", root.name);
            return Err(format_error(path, root.line, why));
        }
        let version = root.attr("commonRoadVersion").unwrap_or("").to_string();
        if version != "2020a" && version != "2018b" {
            let why = format!("CommonRoad version {version:?} (supported: 2020a, 2018b)");
            return Err(CommonRoadError::Unsupported {
                path: path.to_path_buf(),
                reason: why,
            });
        }
        let f = Fields { path };
        let dt_tok = root.attr("timeStepSize").unwrap_or("").trim();
        let dt = f.value(dt_tok, root.line, "timeStepSize", STEP_SIZE)?;
        let lanelets = root
            .children("lanelet")
            .map(|ll| f.lanelet(ll))
            .collect::<Result<Vec<_>, _>>()?;
        if lanelets.is_empty() {
            return Err(format_error(
                path,
                root.line,
                "no <lanelet> elements: no lane map".into(),
            ));
        }
        let obstacles = Self::obstacles(&f, &root, &version)?;
        let planning_problems = root
            .children("planningProblem")
            .map(|pp| f.planning_problem(pp, &lanelets))
            .collect::<Result<Vec<_>, _>>()?;
        let stem = path.file_name().map_or_else(String::new, |s| {
            s.to_string_lossy()
                .split('.')
                .next()
                .unwrap_or("")
                .to_string()
        });
        Ok(Self {
            path: path.to_path_buf(),
            benchmark_id: root.attr("benchmarkID").map_or(stem, str::to_string),
            version,
            dt,
            lanelets,
            obstacles,
            planning_problems,
        })
    }

    fn obstacles(
        f: &Fields<'_>,
        root: &Node,
        version: &str,
    ) -> Result<Vec<RawObstacle>, CommonRoadError> {
        let nodes = dynamic_obstacles(root, version);
        if nodes.is_empty() {
            return Err(format_error(
                f.path,
                root.line,
                "no dynamic obstacles (vehicles) in the scene".into(),
            ));
        }
        let mut out: Vec<RawObstacle> = Vec::with_capacity(nodes.len());
        for ob in nodes {
            let o = f.obstacle(ob)?;
            if let Some(first) = out.iter().find(|p| p.id == o.id) {
                let why = format!("appears twice (first at line {})", first.line);
                return Err(f.err(o.line, &format!("obstacle {} id", o.id), why));
            }
            out.push(o);
        }
        Ok(out)
    }
}
