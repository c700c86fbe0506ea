// Drive a `fake-marlin report` page in headless Chromium with playwright-core and print what a
// reader would see, as one JSON object on stdout (tests/test_report_browser.py judges it).
//
// node report_page_driver.js PAGE.html SCREENSHOT.png SEARCH [CHROMIUM]
// Runs from the npm install directory of playwright-core (NODE_PATH points there).
const { chromium } = require("playwright-core");

async function main() {
  const [page_path, screenshot, search, executable] = process.argv.slice(2);
  const browser = await chromium.launch({
    executablePath: executable || "/usr/bin/chromium",
    headless: true,
    args: ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync"],
  });
  const result = { console_errors: [], requests: [] };
  try {
    const context = await browser.newContext({ viewport: { width: 1400, height: 1000 } });
    const page = await context.newPage();
    page.on("console", (message) => {
      if (message.type() === "error" || message.type() === "warning") {
        result.console_errors.push(`${message.type()}: ${message.text()}`);
      }
    });
    page.on("pageerror", (error) => result.console_errors.push(`pageerror: ${error.message}`));
    page.on("request", (request) => {
      if (!request.url().startsWith("file:") && !request.url().startsWith("data:")) {
        result.requests.push(request.url());
      }
    });
    await page.goto("file://" + page_path, { waitUntil: "load" });
    result.title = await page.title();
    result.svgs = await page.locator("figure.plot svg").count();
    result.svg_paths = await page.locator("figure.plot svg path").count();
    result.svg_box = await page.locator("figure.plot svg").first().boundingBox();
    result.cards = await page.locator("#summary .card").count();
    result.verdict = (await page.locator("#verdict").innerText()).trim();
    result.kinds = await page.locator("#kinds input").evaluateAll(
      (inputs) => inputs.map((input) => [input.dataset.kind, input.checked]));
    result.rows_before = await page.locator("#log-table tbody tr").count();
    result.count_before = await page.locator("#log-count").innerText();
    await page.screenshot({ path: screenshot, fullPage: true });
    await page.locator("figure.plot").screenshot({ path: screenshot.replace(/\.png$/, "-plot.png") });

    await page.locator("#search").pressSequentially(search, { delay: 20 });
    // The page marks the table with the query its rows were filtered by once it has drawn them.
    await page.waitForFunction(
      (query) => document.getElementById("log-table").dataset.query === query,
      search.toLowerCase(), { timeout: 10000 });
    result.rows_after = await page.locator("#log-table tbody tr").count();
    result.count_after = await page.locator("#log-count").innerText();
    result.texts_after = await page.locator("#log-table tbody td.text").allInnerTexts();
    result.marks_after = await page.locator("#log-table tbody mark").count();

    // Untick every kind but `reject`: only the printer's refusals are left.
    await page.locator("#search").fill("");
    await page.waitForFunction(() => document.getElementById("log-table").dataset.query === "");
    for (const [kind, checked] of result.kinds) {
      if ((kind === "reject") !== checked) {
        await page.locator(`#kinds input[data-kind="${kind}"]`).click();
      }
    }
    result.kinds_only_reject = await page.locator("#log-table tbody tr .tag").allInnerTexts();
    result.count_only_reject = await page.locator("#log-count").innerText();
    await page.locator("#log").scrollIntoViewIfNeeded();
    await page.screenshot({ path: screenshot.replace(/\.png$/, "-rejects.png") });

    // A click on the first reject's time shows it among the conversation.
    await page.locator("#log-table tbody td.time a").first().click();
    result.context_target = await page.locator("#log-table tbody tr.target .tag").allInnerTexts();
    result.context_kinds = [...new Set(await page.locator("#log-table tbody tr .tag").allInnerTexts())];
    result.context_count = await page.locator("#log-count").innerText();
    await page.screenshot({ path: screenshot.replace(/\.png$/, "-context.png") });
  } finally {
    await browser.close();
  }
  process.stdout.write(JSON.stringify(result) + "\n");
}

main().catch((error) => {
  process.stderr.write(String(error && error.stack || error) + "\n");
  process.exit(1);
});
