//! What `prt bake` writes besides the container: `report.md` and `report.json` (markdown),
//! the slice images (images) and the plots (plots).

mod images;
mod markdown;
mod plots;

pub use images::write_images;
pub use markdown::{Report, table_markdown, write_report};
