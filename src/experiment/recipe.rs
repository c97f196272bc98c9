//! The named recipes, in one place: how the training data are recorded (sessions,
//! placements, the paths' order), whether the second half of the sessions is recorded
//! again with a round-0 model compensating (closed loop), and how often the models
//! predict in the loop. Every command that records or evaluates starts from one
//! (`demo`, `reproduce`, `scale`, `simulate --trajectory training`, Python's
//! `record_data`), and every report names the one it ran.

use crate::twin::{PathOrder, Placement, Recipe};

/// A recipe with a name.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NamedRecipe {
    /// Its name on the command line and in reports.
    pub name: &'static str,
    /// What it is, in a few words.
    pub summary: &'static str,
    /// How the training sessions are recorded.
    pub sessions: Recipe,
    /// Whether the second half of the sessions is recorded again with a round-0
    /// IASTGCN compensating, at the prediction rate `every`, and trained on.
    pub closed_loop: bool,
    /// A prediction every this many control ticks in the loop.
    pub every: usize,
}

/// The best recipe measured (docs/results.md "Training on what use looks like"): each
/// path's minutes in 4 sessions on days of their own, at spread placements (at 8 minutes
/// per path 4 sessions beat 1 in 4 of 8 closed-loop cells and lost none; at 32 minutes in
/// 5 of 8, and 16 sessions gained nothing over 4; spread placements beat the quarter
/// turns on Hilbert at 8 and 32 minutes by +3.8 / +3.4 and +3.9 / +4.7 points and lost no
/// cell; rotating the paths' order changed nothing); the second half recorded again
/// closed loop, and a prediction every tick (+4.5 points on Hilbert at 32 minutes per
/// path against every 5 ticks, which open-loop-trained models do not gain).
pub const USE_LIKE: NamedRecipe = NamedRecipe {
    name: "use-like",
    summary: "4 cold sessions at spread placements, the second half recorded again with a \
              round-0 model compensating, a prediction every tick",
    sessions: Recipe {
        sessions: 4,
        placement: Placement::Spread,
        path_order: PathOrder::Fixed,
    },
    closed_loop: true,
    every: 1,
};

/// The paper's protocol: one session on the calibration day at the training placement,
/// open loop, a prediction every 5 ticks. The study measured it worst of those it tried.
pub const PAPER: NamedRecipe = NamedRecipe {
    name: "paper",
    summary: "the paper's single session at the training placement, open loop, a \
              prediction every 5 ticks",
    sessions: Recipe::SINGLE,
    closed_loop: false,
    every: 5,
};

/// Every named recipe, the default first.
pub const RECIPES: [NamedRecipe; 2] = [USE_LIKE, PAPER];

/// What every command runs unless told otherwise: the best measured.
pub const DEFAULT: NamedRecipe = USE_LIKE;

impl NamedRecipe {
    /// The report's line for a run of `sessions`, `closed_loop` and `every`: the named
    /// recipe it is, or the nearest one (fewest settings apart; the default on a tie) and
    /// what the run changed.
    pub fn line_for(sessions: &Recipe, closed_loop: bool, every: usize) -> String {
        let apart = |r: &NamedRecipe| r.changes(sessions, closed_loop, every).len();
        let mut nearest = DEFAULT;
        for r in RECIPES {
            if apart(&r) < apart(&nearest) {
                nearest = r;
            }
        }
        nearest.line(sessions, closed_loop, every)
    }

    /// The recipe called `name`.
    pub fn parse(name: &str) -> Option<NamedRecipe> {
        RECIPES.iter().copied().find(|r| r.name == name)
    }

    /// The names, for messages: `use-like, paper`.
    pub fn names() -> String {
        RECIPES.map(|r| r.name).join(", ")
    }

    /// The settings of a run of `sessions`, `closed_loop` and `every` that differ from
    /// this recipe's, in words.
    fn changes(&self, sessions: &Recipe, closed_loop: bool, every: usize) -> Vec<String> {
        let mut changed = Vec::new();
        if sessions.sessions != self.sessions.sessions {
            changed.push(format!("{} session(s)", sessions.sessions));
        }
        if sessions.placement != self.sessions.placement {
            changed.push(format!("placements {}", sessions.placement.name()));
        }
        if sessions.path_order != self.sessions.path_order {
            changed.push(format!("paths {}", sessions.path_order.name()));
        }
        if closed_loop != self.closed_loop {
            changed.push(
                if closed_loop {
                    "closed loop"
                } else {
                    "open loop"
                }
                .into(),
            );
        }
        if every != self.every {
            changed.push(format!("a prediction every {every} ticks"));
        }
        changed
    }

    /// A report's line for a run that started from this recipe and ran `sessions`,
    /// `closed_loop` and `every`: the recipe's name and summary, and what the run
    /// changed, if anything.
    pub fn line(&self, sessions: &Recipe, closed_loop: bool, every: usize) -> String {
        let changed = self.changes(sessions, closed_loop, every);
        let default = if *self == DEFAULT {
            ", the default"
        } else {
            ""
        };
        if changed.is_empty() {
            format!("recipe: {}{default} ({})", self.name, self.summary)
        } else {
            format!(
                "recipe: {}{default} ({}), changed: {}",
                self.name,
                self.summary,
                changed.join(", ")
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{NamedRecipe, DEFAULT, PAPER, RECIPES, USE_LIKE};
    use crate::twin::Placement;

    #[test]
    fn each_recipe_is_found_by_its_name_and_the_default_is_the_best_measured() {
        for r in RECIPES {
            assert_eq!(NamedRecipe::parse(r.name), Some(r));
        }
        assert_eq!(NamedRecipe::parse("single"), None);
        assert_eq!(DEFAULT, USE_LIKE);
        assert_eq!(RECIPES[0], DEFAULT);
        assert_eq!(NamedRecipe::names(), "use-like, paper");
        // Each recipe can be recorded at the demo's 8 minutes per path, and closed-loop
        // data need a second half of the sessions.
        for r in RECIPES {
            r.sessions.validate(8.0).unwrap();
            assert!(!r.closed_loop || r.sessions.sessions >= 2, "{}", r.name);
        }
    }

    #[test]
    fn a_reports_line_names_the_recipe_and_what_the_run_changed() {
        let same = USE_LIKE.line(&USE_LIKE.sessions, true, 1);
        assert!(
            same.starts_with("recipe: use-like, the default (4 cold sessions"),
            "{same}"
        );
        assert!(!same.contains("changed"), "{same}");
        let mut two = PAPER.sessions;
        two.sessions = 2;
        two.placement = Placement::Varied;
        let changed = PAPER.line(&two, true, 5);
        assert!(
            changed.starts_with("recipe: paper (the paper's single session"),
            "{changed}"
        );
        assert!(
            changed.ends_with("changed: 2 session(s), placements varied, closed loop"),
            "{changed}"
        );
        let every = USE_LIKE.line(&USE_LIKE.sessions, false, 5);
        assert!(
            every.ends_with("changed: open loop, a prediction every 5 ticks"),
            "{every}"
        );
        // The nearest named recipe says it.
        assert_eq!(
            NamedRecipe::line_for(&PAPER.sessions, false, 5),
            PAPER.line(&PAPER.sessions, false, 5)
        );
        let mut near = PAPER.sessions;
        near.sessions = 2;
        assert_eq!(
            NamedRecipe::line_for(&near, true, 5),
            PAPER.line(&near, true, 5)
        );
        assert_eq!(NamedRecipe::line_for(&USE_LIKE.sessions, false, 5), every);
    }
}
