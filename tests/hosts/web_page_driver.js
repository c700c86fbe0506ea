// Drive the live view (`fake-marlin --web`) in headless Chromium with playwright-core and print
// what a person would see, as one JSON object on stdout (tests/test_web_browser.py judges it).
//
// node web_page_driver.js URL SCREENSHOT.png PRINTER [CHROMIUM]
// PRINTER is the number of the printer a host is streaming to. Runs from the npm install
// directory of playwright-core (NODE_PATH points there).
const { chromium } = require("playwright-core");

async function main() {
  const [url, screenshot, printer, executable] = process.argv.slice(2);
  const origin = new URL(url).origin;
  const browser = await chromium.launch({
    executablePath: executable || "/usr/bin/chromium",
    headless: true,
    args: ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync"],
  });
  const result = { console_errors: [], requests: [] };
  let listening = true;
  try {
    const context = await browser.newContext({ viewport: { width: 1400, height: 1000 } });
    const page = await context.newPage();
    page.on("console", (message) => {
      if (listening && (message.type() === "error" || message.type() === "warning")) {
        result.console_errors.push(`${message.type()}: ${message.text()}`);
      }
    });
    page.on("pageerror", (error) => result.console_errors.push(`pageerror: ${error.message}`));
    page.on("request", (request) => {
      const address = request.url();
      if (!address.startsWith(origin + "/") && !address.startsWith("data:")) {
        result.requests.push(address);
      }
    });

    // The farm: a page of rows, filled by its first event.
    await page.goto(url, { waitUntil: "load" });
    result.title = await page.title();
    await page.waitForFunction(() => +document.getElementById("farm").dataset.updates >= 1,
                               null, { timeout: 20000 });
    result.rows = await page.locator("#rows tr").count();
    result.page_count = await page.locator("#page-count").innerText();
    result.printers_card = await page.locator("#s-printers").innerText();
    const row = page.locator(`#rows tr[data-number="${printer}"]`);
    result.commands_before = await row.locator("td.commands").innerText();
    result.state = await row.locator("td.state").innerText();
    result.host = await row.locator("td.host").innerText();
    // The job's progress changes on the page, without a reload: the same document updated.
    await page.evaluate(() => { window.stillTheSamePage = true; });
    await page.waitForFunction(
      ([number, before]) => {
        const cell = document.querySelector(`#rows tr[data-number="${number}"] td.commands`);
        return cell && cell.textContent !== before;
      }, [printer, result.commands_before], { timeout: 20000 });
    result.commands_after = await row.locator("td.commands").innerText();
    result.same_page = await page.evaluate(() => window.stillTheSamePage === true);
    result.updates = await page.evaluate(() => +document.getElementById("farm").dataset.updates);
    result.rate = await row.locator("td.rate").innerText();
    result.last_command = await row.locator("td.last").innerText();
    result.idle_row = await page.locator('#rows tr[data-number="2"] td.state').innerText();
    await page.screenshot({ path: screenshot });
    await page.screenshot({ path: screenshot.replace(/\.png$/, "-full.png"), fullPage: true });

    // Printer 1's page, from its row: cards, plots and the wire tail, live.
    await row.locator("td.number a").click();
    await page.waitForURL(`**/printer/${printer}`);
    await page.waitForFunction(() => +document.getElementById("printer").dataset.updates >= 3,
                               null, { timeout: 20000 });
    result.printer_title = await page.title();
    result.printer_state = await page.locator("#c-state").innerText();
    result.tail_in = await page.locator("#tail tr.in").count();
    result.tail_out = await page.locator("#tail tr.out").count();
    result.tail_texts = (await page.locator("#tail td.text").allInnerTexts()).slice(-6);
    result.svgs = await page.locator("#plots svg").count();
    result.svg_paths = await page.locator("#plots svg path").count();
    result.svg_box = await page.locator("#plots svg").boundingBox();
    result.plot_titles = await page.locator("#plots svg text.title").allTextContents();
    result.events = await page.locator("#events li").count();
    await page.screenshot({ path: screenshot.replace(/\.png$/, "-printer.png") });

    // A printer the farm does not have (Chromium logs its 404 as an error: expected here).
    listening = false;
    const missing = await page.goto(new URL("/printer/100000", url).href);
    result.missing_status = missing.status();
    result.missing_text = await page.locator(".notfound").innerText();
  } finally {
    await browser.close();
  }
  process.stdout.write(JSON.stringify(result) + "\n");
}

main().catch((error) => {
  process.stderr.write(String(error && error.stack || error) + "\n");
  process.exit(1);
});
