//! `bench trade SCENE`: the accuracy / size / time trade-off of LPM, run side by side on one
//! device by the library's harness ([`lpmsplat::bench::trade`], which says what it runs and
//! writes: trade.json, trade.md, trade.png and trade.html); `bench merge` pools several such
//! results. Here the flags become its settings, or with `--slurm` a sweep of one task a seed.

use super::trade_args::TradeArgs;
use lpmsplat::bench::trade;
use lpmsplat::gpu::GpuOptions;

pub fn run(gpu: &GpuOptions, args: &TradeArgs) -> anyhow::Result<()> {
    // Checked before a sweep is written too, since each of its tasks would refuse them.
    trade::runs_to_train(args.iterations, args.seeds, &args.runs)?;
    if args.slurm.slurm {
        return super::trade_sweep::write(args, &args.slurm);
    }
    trade::run(gpu, &args.settings()?)
}
