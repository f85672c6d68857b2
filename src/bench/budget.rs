//! `bench trade --budget`: one budget, or a grid of them in one command. A budget is a count, a
//! multiple of the initial model's, or a multiple of ADC's own final count at the same seed
//! (`0.5x-adc`, the Taming protocol's budgets). This module plans the cells: which run trains
//! at which budget, under which name, and in which phase (a budget taken from ADC's count
//! waits for a free ADC run of its seed to finish).

use crate::train::density::growth::Budget;

/// One budget of `bench trade`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BenchBudget {
    /// A count or a multiple of the initial model's, as `train --budget`.
    Fixed(Budget),
    /// A multiple of the final count of a free ADC run of the same seed.
    TimesAdc(f64),
}

/// `--budget` of `bench trade`: what `train --budget` takes, or `0.5x-adc`.
pub fn parse_bench_budget(s: &str) -> Result<BenchBudget, String> {
    let t = s.trim();
    if let Some(f) = t.strip_suffix("x-adc") {
        return match f.parse::<f64>() {
            Ok(v) if v > 0.0 && v.is_finite() => Ok(BenchBudget::TimesAdc(v)),
            _ => Err(format!(
                "'{s}' is not a budget relative to ADC's count. Fix: give a positive multiple, \
                 e.g. 0.25x-adc"
            )),
        };
    }
    Budget::parse(t).map(BenchBudget::Fixed)
}

impl BenchBudget {
    /// How run names and the tables call it: `0.5x-adc`, `3x`, `56479`.
    pub fn label(&self) -> String {
        match *self {
            BenchBudget::Fixed(Budget::Count(n)) => n.to_string(),
            BenchBudget::Fixed(Budget::TimesInitial(f)) => format!("{f}x"),
            BenchBudget::TimesAdc(f) => format!("{f}x-adc"),
        }
    }

    /// The count for a seed whose initial model holds `initial` Gaussians and whose free ADC
    /// run ended with `adc` (known once that run finished; `None` before).
    pub fn resolve(&self, initial: usize, adc: Option<usize>) -> Option<usize> {
        match *self {
            BenchBudget::Fixed(b) => Some(b.resolve(initial)),
            BenchBudget::TimesAdc(f) => adc.map(|n| ((n as f64) * f).round().max(1.0) as usize),
        }
    }

    /// What trade.json's settings record (`bench merge` pools files that agree): a single
    /// fixed budget as before the grid existed.
    pub fn setting(budgets: &[BenchBudget]) -> Option<String> {
        match budgets {
            [] => None,
            [BenchBudget::Fixed(b)] => Some(format!("{b:?}")),
            _ => Some(
                budgets
                    .iter()
                    .map(BenchBudget::label)
                    .collect::<Vec<_>>()
                    .join(","),
            ),
        }
    }
}

/// One cell of the benchmark: a run (index into the runs table) at a seed, at one of the
/// budgets (index into `--budget`) or free.
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    pub k: usize,
    /// Index into the seeds.
    pub seed: usize,
    pub budget: Option<usize>,
    /// The name its rows carry: the run's, with `@budget` in a grid.
    pub name: String,
    /// Trained before the others: the free ADC runs that budgets relative to ADC wait for.
    pub reference: bool,
}

/// The cells for runs `selected` (indices into `names`) at `seeds` seeds and `budgets`.
///
/// - No budget, or one fixed budget: one cell a run and seed, named as the run (as before the
///   grid: `adc` capped at the budget, the budget runs filling it).
/// - Otherwise (several budgets, or one relative to ADC) every run trains at every budget,
///   named `RUN@LABEL`; a budget relative to ADC adds a free `adc` reference per seed (first
///   phase), and `adc` itself is not run at `1x-adc` (that is the reference).
pub fn plan_cells(
    names: &[&str],
    selected: &[usize],
    seeds: usize,
    budgets: &[BenchBudget],
) -> anyhow::Result<Vec<Cell>> {
    let relative = budgets
        .iter()
        .any(|b| matches!(b, BenchBudget::TimesAdc(_)));
    let grid = relative || budgets.len() > 1;
    let mut cells = Vec::new();
    if !grid {
        for &k in selected {
            for seed in 0..seeds {
                cells.push(Cell {
                    k,
                    seed,
                    budget: (!budgets.is_empty()).then_some(0),
                    name: names[k].to_string(),
                    reference: false,
                });
            }
        }
        return Ok(cells);
    }
    let mut labels: Vec<String> = Vec::new();
    for b in budgets {
        let l = b.label();
        anyhow::ensure!(
            !labels.contains(&l),
            "bench trade: --budget {l} is given twice. Fix: name each budget once"
        );
        labels.push(l);
    }
    if relative {
        let adc = names
            .iter()
            .position(|&n| n == "adc")
            .expect("the runs table has adc");
        for seed in 0..seeds {
            cells.push(Cell {
                k: adc,
                seed,
                budget: None,
                name: "adc".into(),
                reference: true,
            });
        }
    }
    for &k in selected {
        for (bi, b) in budgets.iter().enumerate() {
            if names[k] == "adc" && *b == BenchBudget::TimesAdc(1.0) {
                continue;
            }
            for seed in 0..seeds {
                cells.push(Cell {
                    k,
                    seed,
                    budget: Some(bi),
                    name: format!("{}@{}", names[k], labels[bi]),
                    reference: false,
                });
            }
        }
    }
    Ok(cells)
}

/// The run a row's name is a cell of (`mcmc+lpm-local@0.5x-adc` → `mcmc+lpm-local`; a merged
/// file's ` [setting]` tag is kept out too).
pub fn run_of(name: &str) -> &str {
    let end = name.find(['@', ' ']).unwrap_or(name.len());
    &name[..end]
}

/// The budget part of a row's name (`@0.5x-adc` → `Some("0.5x-adc")`).
pub fn budget_of(name: &str) -> Option<&str> {
    let rest = &name[name.find('@')? + 1..];
    Some(&rest[..rest.find(' ').unwrap_or(rest.len())])
}

/// The run a guided run is compared with at one count: the same strategy without LPM at the
/// same budget (`mcmc+lpm-local@0.5x-adc` → `mcmc@0.5x-adc`); `None` for runs without LPM.
pub fn unguided(name: &str) -> Option<String> {
    let run = run_of(name);
    let base = &run[..run.find("+lpm")?];
    Some(match budget_of(name) {
        Some(b) => format!("{base}@{b}"),
        None => base.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const NAMES: [&str; 3] = ["adc", "adc-exact", "mcmc"];

    #[test]
    fn budgets_parse_relative_to_adc_and_fixed() {
        assert_eq!(
            parse_bench_budget("0.25x-adc"),
            Ok(BenchBudget::TimesAdc(0.25))
        );
        assert_eq!(
            parse_bench_budget("300k"),
            Ok(BenchBudget::Fixed(Budget::Count(300_000)))
        );
        assert_eq!(
            parse_bench_budget("2x"),
            Ok(BenchBudget::Fixed(Budget::TimesInitial(2.0)))
        );
        for bad in ["0x-adc", "-1x-adc", "nanx-adc", "x-adc", "adc", "1y"] {
            assert!(parse_bench_budget(bad).is_err(), "{bad}");
        }
        assert_eq!(
            BenchBudget::TimesAdc(0.5).resolve(10, Some(1001)),
            Some(501)
        );
        assert_eq!(BenchBudget::TimesAdc(0.5).resolve(10, None), None);
        assert_eq!(
            BenchBudget::Fixed(Budget::TimesInitial(2.0)).resolve(10, None),
            Some(20)
        );
    }

    #[test]
    fn one_fixed_budget_keeps_the_run_names() {
        let b = [BenchBudget::Fixed(Budget::Count(100))];
        let cells = plan_cells(&NAMES, &[0, 2], 2, &b).unwrap();
        let names: Vec<&str> = cells.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(names, ["adc", "adc", "mcmc", "mcmc"]);
        assert!(cells.iter().all(|c| c.budget == Some(0) && !c.reference));
        let free = plan_cells(&NAMES, &[0], 1, &[]).unwrap();
        assert_eq!(free[0].budget, None);
        assert_eq!(
            BenchBudget::setting(&b).as_deref(),
            Some("Count(100)"),
            "a single budget is recorded as before the grid, so older files still pool"
        );
    }

    #[test]
    fn a_grid_relative_to_adc_runs_a_free_reference_first() {
        let b = [BenchBudget::TimesAdc(0.5), BenchBudget::TimesAdc(1.0)];
        let cells = plan_cells(&NAMES, &[0, 2], 2, &b).unwrap();
        let names: Vec<(&str, usize, bool)> = cells
            .iter()
            .map(|c| (c.name.as_str(), c.seed, c.reference))
            .collect();
        assert_eq!(
            names,
            [
                ("adc", 0, true),
                ("adc", 1, true),
                ("adc@0.5x-adc", 0, false),
                ("adc@0.5x-adc", 1, false),
                ("mcmc@0.5x-adc", 0, false),
                ("mcmc@0.5x-adc", 1, false),
                ("mcmc@1x-adc", 0, false),
                ("mcmc@1x-adc", 1, false),
            ]
        );
        let twice = [BenchBudget::TimesAdc(0.5), BenchBudget::TimesAdc(0.5)];
        assert!(plan_cells(&NAMES, &[2], 1, &twice).is_err());
        assert_eq!(BenchBudget::setting(&b).as_deref(), Some("0.5x-adc,1x-adc"));
    }

    #[test]
    fn several_fixed_budgets_make_a_grid_without_a_reference() {
        let b = [
            BenchBudget::Fixed(Budget::Count(100)),
            BenchBudget::Fixed(Budget::TimesInitial(2.0)),
        ];
        let cells = plan_cells(&NAMES, &[1], 1, &b).unwrap();
        let names: Vec<&str> = cells.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(names, ["adc-exact@100", "adc-exact@2x"]);
    }

    #[test]
    fn names_split_into_run_budget_and_unguided_twin() {
        assert_eq!(run_of("mcmc+lpm-local@0.5x-adc"), "mcmc+lpm-local");
        assert_eq!(run_of("adc+lpm [lpm_block=8]"), "adc+lpm");
        assert_eq!(run_of("adc"), "adc");
        assert_eq!(budget_of("mcmc@0.5x-adc [x=1]"), Some("0.5x-adc"));
        assert_eq!(budget_of("mcmc"), None);
        assert_eq!(
            unguided("mcmc+lpm-local@0.5x-adc").as_deref(),
            Some("mcmc@0.5x-adc")
        );
        assert_eq!(unguided("adc-exact+lpm").as_deref(), Some("adc-exact"));
        assert_eq!(unguided("adc+lpm").as_deref(), Some("adc"));
        assert_eq!(unguided("mcmc@1x-adc"), None);
    }
}
