//! `bench trade`'s harness as a library: the runs it can compare ([`runs`]), the budgets of a
//! grid and the runs × seeds × budgets cells they make ([`budget`]), the summary of the rows
//! (means, paired differences, the tables and trade.png: [`summary`]) and the report page with
//! each run's renders ([`report`]), and the harness that trains the cells, evaluates them and
//! writes the results ([`trade`]). The CLI (`src/cli/bench/`) only turns `bench trade`'s flags
//! into [`trade::TradeSettings`] and calls [`trade::run`].

pub mod budget;
pub mod report;
pub mod runs;
pub mod summary;
pub mod trade;
