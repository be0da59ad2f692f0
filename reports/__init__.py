"""Reports: image previews, plots and the HTML report."""
