//! The runs `bench trade` can compare, by name: each one's colour in the plots and what it is.
//! [`super::trade::run_config`] configures them; `--runs`' help is written from this table.

/// A run `bench trade` can compare: its name, its colour in the plots and what it is (the
/// `--runs` help is written from these, so the list there is always this table).
pub struct Run {
    pub name: &'static str,
    pub colour: [u8; 3],
    pub what: &'static str,
}

const fn run(name: &'static str, colour: [u8; 3], what: &'static str) -> Run {
    Run { name, colour, what }
}

pub const RUNS: [Run; 35] = [
    run("adc", [40, 40, 40], "ADC, the base model's own density control"),
    run("adc-threshold-1e-4", [200, 120, 0], "ADC with its gradient threshold halved to 1e-4 (alias adc-1e-4)"),
    run("adc+lpm", [220, 30, 30], "ADC + LPM with our rules (`train --lpm`; alias lpm)"),
    run("lpm-no-add", [30, 120, 220], "our rules without the points added in sparse zones"),
    run("lpm-no-reset", [30, 170, 60], "our rules without LPM's opacity reset"),
    run("lpm-authors", [150, 60, 200], "the authors' code's rules exactly (`--lpm-rules authors`)"),
    run("lpm-authors-adc", [200, 110, 230], "the authors' rules with ADC kept on steps without a zone (`--lpm-skip-adc false`)"),
    run("lpm-sphere", [120, 90, 40], "our rules with the paper's cone-intersection sphere as the zone"),
    run("adc-abs-grad", [90, 90, 90], "ADC with the absolute-gradient test as well (`--densify-abs-grad`)"),
    run("lpm-additive", [240, 150, 150], "our rules with the additive pruning: as many extra prunes as lowered-threshold densifications (`--lpm-prune additive`)"),
    run("lpm-overlap-neighbours", [60, 200, 200], "our rules with the neighbour views sharing the most tracks (`--lpm-neighbours overlap`)"),
    run("lpm-error-blocks", [230, 190, 40], "our rules with only the matches on a region's own error blocks speaking for it (`--lpm-region-keypoints error-blocks`)"),
    run("lpm-bounding-cone", [40, 60, 160], "our rules with the in-front cone to the zone's bounding sphere (`--lpm-cone bounding`, the default before 2026-11-26)"),
    run("lpm-local-zones", [160, 200, 60], "our rules without the zones wider than the scene extent (`--lpm-max-zone-radius 1`)"),
    run("lpm-slab", [200, 80, 200], "our rules with the zone cut to the region's cone and its matches' depths (`--lpm-zone slab`)"),
    run("lpm-loose-blocks", [250, 120, 40], "our rules with error blocks kept above 70 % error pixels, whatever --lpm-block-fraction says"),
    run("lpm-local-resets", [120, 40, 120], "our rules with the zones wider than the scene kept but ignored by the opacity reset (`--lpm-reset-max-zone-radius 1`)"),
    run("adc-exact", [20, 130, 130], "ADC at an exact budget: the best-scoring candidates its growth curve has room for (`--strategy adc-exact`; --budget, or adc's count under --match-adc-count)"),
    run("adc-exact+lpm", [240, 60, 120], "the same guided by LPM's zone weights (count-neutral)"),
    run("adc-exact+lpm-lowered", [140, 20, 60], "the same ranked over LPM's lowered threshold, the paper's rule (`--lpm-rank lowered`)"),
    run("mcmc", [0, 90, 200], "3DGS as MCMC at --budget (`--strategy mcmc`; a start above the budget kept whole and falling to it, or as --budget-draw says)"),
    run("mcmc+lpm", [250, 170, 0], "MCMC guided by LPM: relocation targets and growth sources drawn ∝ opacity × the zone weight"),
    run("adc-exact+lpm-local", [180, 0, 90], "the exact budget guided by zones local by construction (`--lpm-zone local`: one a block, a depth band of observed points, ≤ 1 % of the model)"),
    run("mcmc+lpm-local", [200, 120, 0], "MCMC guided by local zones"),
    run("adc-exact+lpm-random", [130, 130, 130], "the control: local zones on as many blocks drawn at random (`--lpm-regions random-blocks`): what the error map adds"),
    run("mcmc+lpm-surface", [0, 160, 80], "MCMC guided by local zones, half of each refinement's dead Gaussians moved onto the zones' SfM points coloured from the ground truth (`--lpm-surface-share 0.5`)"),
    run("mcmc+lpm-surface-random", [110, 160, 130], "the control of mcmc+lpm-surface: the same on as many blocks drawn at random"),
    run("mcmc-refit", [90, 150, 230], "MCMC whose start, drawn down to a budget below it, has its scales refitted to the kept points' spacing (`--budget-refit-scales`)"),
    run("mcmc-spread", [0, 40, 120], "the same drawn spread over the cloud: one Gaussian from each cell of the finest grid the budget allows (`--budget-draw spread --budget-refit-scales`)"),
    run("mcmc-start", [100, 200, 250], "MCMC from its own start as gsplat ships it: opacity 0.5, a tenth of the neighbours' spacing (`--init-opacity 0.5 --init-scale 0.1`)"),
    run("mcmc-keep", [20, 160, 200], "MCMC from every initial Gaussian at a budget below them: the count falls to the budget along the densify window, the least opaque removed at each refinement (`--budget-draw keep`)"),
    run("mcmc-drawn", [70, 70, 200], "MCMC from a start above the budget drawn down to it at random (`--budget-draw random`): what mcmc ran until keep became its default"),
    run("adc-exact-blend", [0, 180, 110], "the exact budget ranked by Taming-3DGS's blended score over 10 sampled views instead of the gradient statistic (`--budget-score blend`)"),
    run("adc-exact-blend+lpm-local", [220, 90, 40], "the same guided by local zones: each score times the zone weight"),
    run("mcmc-opaque", [160, 60, 20], "MCMC from points of opacity 0.5 at the neighbours' spacing (`--init-opacity 0.5`)"),
];

/// The `--runs` help: every run of [`RUNS`] with what it is, in table order.
pub fn runs_help() -> String {
    let mut h = String::from(
        "The runs to compare, comma separated; they are reported in this table's order. \
         Default: the first five.\n",
    );
    for r in &RUNS {
        h.push_str(&format!("\n- {}: {}", r.name, r.what));
    }
    h
}
