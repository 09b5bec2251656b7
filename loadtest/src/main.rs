//! `dynaserve-loadtest`: see the crate documentation and `loadtest/README.md`.

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> anyhow::Result<()> {
    let code = dynaserve_loadtest::cli::main()?;
    if code != 0 {
        std::process::exit(code);
    }
    Ok(())
}
