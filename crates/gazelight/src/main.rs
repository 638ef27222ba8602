//! The gazelight CLI.

fn main() -> anyhow::Result<()> {
    Ok(())
}
