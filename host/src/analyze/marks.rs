//! Event marks on the survey line: each recorded mark
//! ([`crate::recording::mark`]) at the chainage of the odometer it was
//! made at, by the same placement as its run's frames.
//!
//! A mark holds the odometer of the latest profile before it: the head's
//! track position `x = odometer` (a frame's points lie at `odometer ±
//! along` about it, [`super::stitch`]), placed as the run is ([`super::survey`]:
//! its start chainage as used, registration's shift included, and its
//! heading, chainage down the line for a run that runs down). So a mark
//! lies where the frame before it lies, to within the travel of one frame
//! (plus the operator's reaction). A run that was not placed (no
//! calibrated line) leaves its marks without a chainage.

use super::survey::{self, RunJoin};
use super::{Source, chainage};
use crate::recording::mark::Mark;

/// A mark on the line.
#[derive(Debug, Clone, PartialEq)]
pub struct PlacedMark {
    /// Its run, from 1.
    pub run: usize,
    /// The mark as recorded.
    pub mark: Mark,
    /// Its chainage, mm (`None`: its run was not placed).
    pub chainage_mm: Option<f64>,
}

impl PlacedMark {
    /// Its chainage as `km+m`, or why there is none.
    pub fn chainage(&self) -> String {
        self.chainage_mm.map_or_else(|| "not placed".to_string(), chainage)
    }
}

/// Every run's marks at their chainage, in chainage order (unplaced last,
/// in file order).
pub fn placed(source: &Source, joins: &[RunJoin]) -> Vec<PlacedMark> {
    let Source::Recordings(runs) = source else { return Vec::new() };
    let mut out: Vec<PlacedMark> = runs
        .iter()
        .enumerate()
        .flat_map(|(i, (_, rec))| {
            let join = joins.iter().find(|j| j.run == i + 1);
            rec.marks.iter().map(move |m| PlacedMark {
                run: i + 1,
                mark: m.clone(),
                chainage_mm: join.map(|j| at(j, m.odometer_mm())),
            })
        })
        .collect();
    out.sort_by(|a, b| match (a.chainage_mm, b.chainage_mm) {
        (Some(x), Some(y)) => x.total_cmp(&y),
        (Some(_), None) => std::cmp::Ordering::Less,
        (None, Some(_)) => std::cmp::Ordering::Greater,
        (None, None) => std::cmp::Ordering::Equal,
    });
    out
}

/// The chainage of track position `x_mm` of a run placed as `j`, mm.
pub fn at(j: &RunJoin, x_mm: f64) -> f64 {
    survey::to_chainage(j.start_m * 1000.0, j.heading, x_mm)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analyze::Recording;
    use crate::analyze::stitch::Direction;
    use crate::recording::mark::MarkKind;
    use crate::recording::survey_info::Heading;

    fn join(run: usize, start_m: f64, heading: Heading) -> RunJoin {
        RunJoin {
            run,
            section: 1,
            heading,
            start_m,
            moved_mm: None,
            heading_found: false,
            heading_disputed: None,
            elsewhere: None,
            direction: Direction::Forward,
            direction_disputed: None,
            overlap_mm: 0.0,
            residual_um: None,
            correlation: None,
        }
    }

    fn mark(kind: MarkKind, odometer_um: i64) -> Mark {
        Mark { kind, text: String::new(), host_us: 0, seq: 0, head_us: 0, odometer_um, after_us: 0 }
    }

    #[test]
    fn marks_lie_at_their_runs_chainage_up_and_down() {
        let rec = |marks: Vec<Mark>| Recording { marks, ..Recording::default() };
        let source = Source::Recordings(vec![
            ("a".into(), rec(vec![mark(MarkKind::Weld, 1_500_000), mark(MarkKind::Joint, 250_000)])),
            ("b".into(), rec(vec![mark(MarkKind::Defect, 2_000_000)])),
            ("c".into(), rec(vec![mark(MarkKind::Note, 0)])),
        ]);
        // Run 1 up from 12+345, run 2 down from 12+360; run 3 not placed.
        let joins = [join(1, 12_345.0, Heading::Up), join(2, 12_360.0, Heading::Down)];
        let p = placed(&source, &joins);
        let got: Vec<(usize, MarkKind, Option<f64>)> =
            p.iter().map(|m| (m.run, m.mark.kind, m.chainage_mm.map(|c| (c * 1000.0).round() / 1000.0))).collect();
        assert_eq!(
            got,
            vec![
                (1, MarkKind::Joint, Some(12_345_250.0)),
                (1, MarkKind::Weld, Some(12_346_500.0)),
                (2, MarkKind::Defect, Some(12_358_000.0)),
                (3, MarkKind::Note, None),
            ]
        );
        assert_eq!(p[1].chainage(), "12+346.500");
        assert_eq!(p[3].chainage(), "not placed");
    }
}
