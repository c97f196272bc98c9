//! `iastgcn smoke`: arguments for the library's device check ([`iastgcn::smoke::smoke()`])
//! and its printout; fails when a kernel does not match the CPU reference.

use anyhow::bail;

use iastgcn::gpu::Gpu;
use iastgcn::smoke::{smoke, SmokeOptions, SmokeRow};

#[derive(clap::Args)]
pub struct SmokeArgs {
    /// Seed of the random inputs.
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Rows of the activation matrix (B·N·T of a layer); 1400 = 1 window of 14 nodes × 100 steps.
    #[arg(long, default_value_t = 1400)]
    rows: usize,
    /// Channels (C of docs/model.md).
    #[arg(long, default_value_t = 64)]
    channels: usize,
}

pub fn run(gpu: &Gpu, args: &SmokeArgs) -> anyhow::Result<()> {
    println!("smoke test on {}", gpu.info().name);
    let rows = smoke(
        gpu,
        &SmokeOptions {
            seed: args.seed,
            rows: args.rows,
            channels: args.channels,
        },
    )?;
    print_rows(&rows);
    let failed: Vec<&str> = rows
        .iter()
        .filter(|r| !r.pass)
        .map(|r| r.name.as_str())
        .collect();
    if !failed.is_empty() {
        bail!(
            "{} of {} kernel checks do not match the CPU reference: {}",
            failed.len(),
            rows.len(),
            failed.join(", ")
        );
    }
    println!("all kernels match the CPU reference");
    Ok(())
}

/// One line per group of kernels (its time, GFLOP/s where counted, worst relative
/// error), then one line per tensor compared.
fn print_rows(rows: &[SmokeRow]) {
    for (i, row) in rows.iter().enumerate() {
        if i == 0 || rows[i - 1].group != row.group {
            let group = rows.iter().filter(|r| r.group == row.group);
            let worst = group.map(|r| r.worst.rel_err).fold(0.0, f64::max);
            let speed = match row.flops {
                Some(flops) => format!("  {:6.2} GFLOP/s", flops / row.seconds / 1e9),
                None => String::new(),
            };
            let compile = if row.includes_compile {
                " (first run, includes JIT)"
            } else {
                ""
            };
            println!(
                "  {}  {:7.2} ms{compile}{speed}  worst rel err {worst:.1e}",
                row.group,
                row.seconds * 1e3,
            );
        }
        let (w, tol) = (&row.worst, &row.tolerance);
        if row.pass {
            println!(
                "    {:<20} ok    worst element abs err {:.1e}, rel err {:.1e} ({:.2} of tolerance)",
                row.name, w.abs_err, w.rel_err, w.ratio
            );
        } else {
            println!(
                "    {:<20} FAIL  {w} (tolerance abs {:.1e} + rel {:.1e})",
                row.name, tol.abs, tol.rel
            );
        }
    }
}
